"""The firmware's hardware paths that the emulator can show (issue: "what only the board would
show"): every PLC rate works on the L475's PLC UART, a long PLC reply at a low rate neither
starves the watchdog nor delays the stop input, and the watchdog does reset a firmware that stops
making progress.

QEMU moves UART bytes at once and has no IWDG. The emulator build therefore models both: its PLC
line lasts as long as a reply's characters take on the wire at the line's rate and framing
(`emu::Pace` in src/emu.rs), and a watchdog on the SysTick interrupt resets the machine after the shortest
time the board's IWDG may take (0.67 s: the F103's LSI at its fastest). What they stand in for,
the UART's timing and the IWDG itself, is for the board's bring-up checklist.
"""

import time

from emu import STOP_INPUT
from plc import GATEWAY_UNIT, G_FAILSAFE, G_VERSION, G_WATCHDOG, unit, wait_for

from test_modbus import _apply, online

PLCBAUD, PLCPARITY, RESETCAUSE, UPTIME = 0x0010, 0x0011, 0x001A, 0x0002
DIAG = 0x0400  # 256 counters: the longest read a PLC can ask for (125 registers)
USART2 = 0x4000_4400  # the PLC line's UART
CR1, BRR = 0x00, 0x0C
HSI16 = 16_000_000


def slow_plc_line(emu):
    """The PLC line at 1.2 kbit/s, even parity: the lowest rate PLCBAUD offers."""
    plc = online(emu)
    plc.write(GATEWAY_UNIT, PLCBAUD, 12)
    plc.write(GATEWAY_UNIT, PLCPARITY, 2)
    wait_for(lambda: _apply(plc), 10, "APPLY taken (refused with 03 while the bus is busy)")
    return plc


def test_the_plc_line_works_at_1200_bit_s(emu):
    # At 80 MHz the divider for 1.2 kbit/s (66,667) does not fit the 16-bit BRR; the driver then
    # refused the rate after disabling the UART, and the line went dead. USART2 is clocked by
    # HSI16 now: the divider is 13,333 and the UART stays enabled.
    plc = slow_plc_line(emu)
    wait_for(lambda: emu.qtest.readl(USART2 + BRR) == round(HSI16 / 1200), 5, "BRR set for 1.2 kbit/s")
    assert emu.qtest.readl(USART2 + CR1) & 1, "USART2 enabled (UE)"
    assert plc.read(GATEWAY_UNIT, PLCBAUD) == [12]
    assert plc.read(GATEWAY_UNIT, G_VERSION, 2)[0] > 0, "the line answers at its new rate"
    assert plc.read(unit(0), 0x9F02) == [1], "and the axis is still online behind it"


def test_a_long_reply_at_1200_bit_s_feeds_the_watchdog_and_a_stop_is_not_delayed(emu):
    plc = slow_plc_line(emu)
    assert plc.read(GATEWAY_UNIT, PLCBAUD) == [12]
    # The PLC watchdog shorter than the reply: the PLC's silence counts from the reply's end.
    plc.write(GATEWAY_UNIT, G_WATCHDOG, 1500)
    before = plc.read(GATEWAY_UNIT, RESETCAUSE)[0]
    uptime = plc.read(GATEWAY_UNIT, UPTIME, 2)
    commands = len(emu.bus_commands(0))
    # 125 registers: 255 bytes of 11 bits at 1.2 kbit/s, 2.34 s on the wire, three and a half
    # times the watchdog's shortest timeout. The reply itself comes back at once (QEMU), while
    # the firmware's line is busy with it for its wire time.
    sent = time.monotonic()
    assert len(plc.read(GATEWAY_UNIT, DIAG, 125)) == 125
    # The cabinet's stop chain opens while the reply is on the wire: the stop reaches the bus
    # at once, not after the reply (a task that waited for the reply sent it 2 s later).
    time.sleep(0.2)
    opened = time.monotonic()
    emu.set_pin(STOP_INPUT, False)
    wait_for(lambda: any(c[2] == "CancelMotion" for c in emu.bus_commands(0)[commands:]), 1.5,
             "the stop on the bus while the reply is still on the wire")
    assert time.monotonic() - sent < 2.34, "checked within the reply's wire time"
    print(f"stop on the bus {time.monotonic() - opened:.3f} s after the input opened")
    # Past the reply's wire time (and the watchdog model's, twice): no reset. The PLC asks
    # again as soon as the reply has ended: its watchdog has not tripped (it would have, 1.5 s
    # after the request, if the silence counted from the request).
    time.sleep(max(0.0, sent + 2.6 - time.monotonic()))
    assert plc.read(GATEWAY_UNIT, G_FAILSAFE)[0] & 1 == 0, "the PLC watchdog did not trip"
    time.sleep(max(0.0, sent + 3.0 - time.monotonic()))
    assert not any("watchdog" in line for line in emu.log()), "the watchdog did not fire"
    assert sum("starting" in line for line in emu.log()) == 1, "the firmware did not restart"
    after = plc.read(GATEWAY_UNIT, UPTIME, 2)
    assert (after[0] << 16 | after[1]) >= (uptime[0] << 16 | uptime[1]) + 2, "uptime went on"
    assert plc.read(GATEWAY_UNIT, RESETCAUSE)[0] == before


def test_the_watchdog_resets_a_firmware_that_stops_making_progress(emu):
    # The other half of the proof: the model is armed and does reset (so the test above would
    # have caught a starved watchdog).
    plc = online(emu)
    assert plc.read(GATEWAY_UNIT, G_VERSION, 2)[0] > 0
    emu.qtest.cmd(f"writeb {emu.symbols['EMU_STALL']:#x} 0x1")
    line = emu.wait_log("watchdog: no progress", 5)
    since = int(line.split("for ")[1].split(" ms")[0])
    assert 660 <= since <= 1000, line
    # QEMU resets the machine as the IWDG does the chip: the firmware starts again, and serves.
    wait_for(lambda: sum("INFO  ready" in line for line in emu.log()) == 2, 20, "a second start")
    wait_for(lambda: plc.read(GATEWAY_UNIT, G_VERSION, 2)[0] > 0, 10, "the PLC line answers again")
