"""The real firmware ELF in QEMU, driven over Modbus RTU by pymodbus, with rc-sim's controllers on
its bus: what a PLC on the gateway's Modbus line sees, and what the controllers receive.

QEMU moves bytes without wire time and its clock follows real time only loosely: the tests check
behaviour and order, with generous time limits, never timing. The simulated axis is the
firmware's default configuration (axis 0 = unit 1; 6 mm lead, 100 mm stroke), homed at the motor
end; targets stay within 70 mm so that they are inside the simulator's own stroke too.
"""

import time

import pytest

from emu import LED_ALARM, LED_LINK, STOP_INPUT
from plc import (
    ALMC,
    CMCT,
    COIL_ALRS,
    COIL_STOP,
    DONE,
    DOPM,
    DOPM_ALM_N,
    DRG1,
    DRG1_CSTR,
    DRG1_SON,
    DSS1_ALMH,
    DSS1_PEND,
    DSS1_SV,
    FAILED,
    G_FAILSAFE,
    G_PIO_AXIS,
    G_SYNC_MASK,
    G_VERSION,
    G_WATCHDOG,
    GATEWAY_UNIT,
    ILLEGAL_DATA_ADDRESS,
    ILLEGAL_DATA_VALUE,
    ILLEGAL_FUNCTION,
    LINK,
    ModbusError,
    LINK_OFFLINE,
    LINK_ONLINE,
    POSR,
    REASON_ALARM,
    REASON_CANCELLED,
    SERVER_FAILURE,
    adu,
    unit,
    wait_for,
)

ROW = 0x1000  # position table: row n at 0x1000 + 16 n
AXISCFG, APPLY = 0x0100, 0x000A  # gateway unit: axis n's configuration at 0x0100 + 8 n


def _apply(plc):
    try:
        plc.write(GATEWAY_UNIT, APPLY, 1)
        return True
    except ModbusError as refused:
        assert refused.code == ILLEGAL_DATA_VALUE
        return False


def online(emu, axis=0, timeout=20):
    """Waits until the gateway has established the bus (the line at 115.2 kbit/s) and the axis
    answers (LINK 1); then closes the stop input (the cabinet's stop chain, wired ON: an open
    stop input blocks every motion) and takes the discrete I/O off axis 0 (PIOAXIS none), as a
    Modbus-only installation does: with it, the SON input (OFF, nothing wired) would own the
    servo and an OFF *STP would stop every move."""
    emu.set_pin(STOP_INPUT, True)
    # The stop input was open at power-up: latched in FAILSAFE (bit 1) until acknowledged.
    wait_for(lambda: emu.plc.read(GATEWAY_UNIT, G_FAILSAFE)[0] & 2, 5, "the stop latched")
    emu.plc.acknowledge()
    assert emu.plc.read(GATEWAY_UNIT, G_FAILSAFE)[0] == 0
    wait_for(lambda: established(emu.bus_events()), timeout, "bus established")
    wait_for(lambda: emu.plc.read(unit(axis), LINK)[0] == LINK_ONLINE, timeout, f"axis {axis} online")
    emu.plc.write(GATEWAY_UNIT, G_PIO_AXIS, 0xFFFF)
    assert emu.plc.read(GATEWAY_UNIT, G_PIO_AXIS) == [0xFFFF]
    # The PLC watchdog off: on a loaded host QEMU can stall for longer than its 1 s, which the
    # firmware rightly takes for a silent PLC (a stop, FAILSAFE latched, the alarm LED on). The
    # watchdog's own test sets it.
    emu.plc.write(GATEWAY_UNIT, G_WATCHDOG, 0)
    return emu.plc


def established(events):
    """Whether the §6-1 establishment has ended: the master at 115.2 kbit/s after the
    communication change. (The UART is at 115.2 kbit/s for a moment at start-up too, before the
    establishment drops it to 9600: that one does not count.)"""
    changes = [i for i, e in enumerate(events) if "communication-change" in e]
    return bool(changes) and any("master at 115200" in e for e in events[changes[0]:])


def row(position, speed=50_00, accel=30, band=10):
    """A position-table row (15 registers): PCMD, INP, VCMD, zones 0, ACMD, DCMD, PPOW 0, LPOW 0,
    CTLF 0."""
    return [position >> 16, position & 0xFFFF, band >> 16, band & 0xFFFF, speed >> 16,
            speed & 0xFFFF, 0, 0, 0, 0, accel, accel, 0, 0, 0]


def test_the_bus_is_established_and_the_axis_comes_online(emu):
    plc = online(emu)
    events = emu.bus_events()
    # §6-1: break, RTIM set at the power-up rate, the communication change, then the new rate.
    breaks = [i for i, e in enumerate(events) if "break" in e]
    changes = [i for i, e in enumerate(events) if "communication-change" in e]
    fast = [i for i, e in enumerate(events) if "master at 115200" in e]
    assert breaks and changes and fast, events
    assert breaks[-1] < changes[0] < fast[-1], events
    commands = [c[2] for c in emu.bus_commands(0)]
    assert "SetResponseDelay" in commands, commands
    time.sleep(0.3)
    assert emu.bus_commands(0)[-1][2] in ("Status", "ReadMemory"), "then polled"
    # The version register and the bus link LED.
    assert plc.read(GATEWAY_UNIT, G_VERSION)[0] != 0
    wait_for(lambda: plc.dss1(0) is not None and emu.odr(LED_LINK) == 1, 5, "bus link LED on")


def test_servo_home_and_move_to_a_point_written_and_read_back(emu):
    plc = online(emu)
    plc.home(0)
    assert plc.dss1(0) & DSS1_SV
    assert "Home" in [c[2] for c in emu.bus_changes(0)]
    # Row 2: 30.00 mm. Written as a whole row, compared with the controller, stored, verified.
    plc.write(unit(0), ROW + 2 * 16, row(30_00))
    readback = wait_for(lambda: _read_row(plc, 2), 10, "row 2 readable")
    assert readback[:6] == row(30_00)[:6], readback
    assert "StoreFromEdit" in [c[2] for c in emu.bus_changes(0)], "stored with V5"
    plc.write(unit(0), POSR, 2)
    plc.write(unit(0), DRG1, DRG1_SON | DRG1_CSTR)
    assert plc.settle(0) == (DONE, 0)
    wait_for(lambda: plc.dss1(0) & DSS1_PEND and plc.pnow(0) == 30_00, 10, "PEND at 30.00 mm")
    assert plc.read(unit(0), DOPM)[0] & 0xF == 2, "PM1-PM8 show point 2"
    assert "MoveToPoint" in [c[2] for c in emu.bus_changes(0)]
    plc.write(unit(0), DRG1, DRG1_SON)


def _read_row(plc, n):
    try:
        return plc.read(unit(0), ROW + n * 16, 15)
    except Exception as error:  # 04 while the gateway fetches the row from the controller
        if getattr(error, "code", None) == SERVER_FAILURE:
            return None
        raise


def test_direct_move_then_stop(emu):
    plc = online(emu)
    plc.home(0)
    plc.direct(0, 20_00, speed=50_00)
    assert plc.settle(0) == (DONE, 0)
    wait_for(lambda: plc.pnow(0) == 20_00, 10, "PNOW 20.00 mm")
    # A slow move, stopped on the way: 10 mm/s toward 70 mm.
    plc.direct(0, 70_00, speed=10_00)
    wait_for(lambda: plc.pnow(0) > 21_00, 10, "moving")
    plc.coil(unit(0), COIL_STOP, True)
    wait_for(lambda: plc.cmst(0)[0] != 1, 10, "the move ends")
    assert plc.cmst(0) == (FAILED, REASON_CANCELLED << 8)
    time.sleep(0.5)
    stopped = plc.pnow(0)
    time.sleep(0.5)
    assert plc.pnow(0) == stopped, "standing still"
    assert 20_00 < stopped < 50_00, stopped
    assert "CancelMotion" in [c[2] for c in emu.bus_changes(0)]
    assert plc.read(unit(0), CMCT)[0] == 4, "SON, HOME, two moves (a stop is not counted)"


def test_with_no_pio_axis_the_stop_input_wakes_the_firmware_by_its_interrupt(emu):
    """With no PIO axis the I/O task no longer samples every millisecond: it sleeps until the
    stop input's pin-change interrupt (EXTI) or its 20 ms LED tick. Opening the stop input
    mid-move stops the axis and latches FAILSAFE bit 1, and the interrupt is what woke the task
    (EMU_STOP_WAKES counts those wakes: the LED tick alone would stop the axis too)."""
    plc = online(emu)
    plc.home(0)
    wakes = emu.qtest.readl(emu.symbols["EMU_STOP_WAKES"])
    plc.direct(0, 70_00, speed=10_00)
    wait_for(lambda: plc.pnow(0) > 2_00, 10, "moving")
    before = len(emu.bus_changes(0))
    emu.set_pin(STOP_INPUT, False)  # the stop chain opens
    wait_for(lambda: plc.read(GATEWAY_UNIT, G_FAILSAFE)[0] & 2, 5, "the stop latched")
    wait_for(lambda: plc.cmst(0)[0] != 1, 10, "the move ends")
    assert "CancelMotion" in [c[2] for c in emu.bus_changes(0)[before:]]
    assert emu.qtest.readl(emu.symbols["EMU_STOP_WAKES"]) > wakes, "woken by the interrupt"
    time.sleep(0.5)
    stopped = plc.pnow(0)
    time.sleep(0.5)
    assert plc.pnow(0) == stopped, "standing still"
    assert stopped < 70_00, stopped


def test_alarm_and_reset(emu):
    plc = online(emu)
    plc.home(0)
    # Point 9 was never written: the controller refuses the move with an alarm (B1).
    plc.write(unit(0), POSR, 9)
    plc.write(unit(0), DRG1, DRG1_SON | DRG1_CSTR)
    wait_for(lambda: plc.dss1(0) & DSS1_ALMH, 10, "ALMH")
    assert plc.read(unit(0), ALMC)[0] == 0xB1
    assert not plc.read(unit(0), DOPM)[0] & DOPM_ALM_N, "*ALM off (active low)"
    state, reason = plc.settle(0)
    assert (state, reason >> 8) == (FAILED, REASON_ALARM), (state, reason)
    # (Each wait reads a register too: the PLC watchdog, 1 s, must not see silence.)
    wait_for(lambda: plc.dss1(0) is not None and emu.odr(LED_ALARM) == 1, 5, "alarm LED on")
    plc.write(unit(0), DRG1, DRG1_SON)
    plc.coil(unit(0), COIL_ALRS, True)
    wait_for(lambda: not plc.dss1(0) & DSS1_ALMH, 10, "alarm cleared")
    assert plc.read(unit(0), ALMC)[0] == 0
    assert plc.read(unit(0), DOPM)[0] & DOPM_ALM_N
    plc.coil(unit(0), COIL_ALRS, False)
    wait_for(lambda: plc.dss1(0) is not None and emu.odr(LED_ALARM) == 0, 5, "alarm LED off")
    assert "Reset" in [c[2] for c in emu.bus_changes(0)]


def test_the_watchdog_stops_a_moving_axis_when_the_plc_falls_silent(emu):
    plc = online(emu)
    plc.home(0)
    plc.write(GATEWAY_UNIT, G_WATCHDOG, 500)
    assert plc.read(GATEWAY_UNIT, G_FAILSAFE, 2) == [0, 1], "the stop at power-up was counted"
    plc.direct(0, 70_00, speed=10_00)
    wait_for(lambda: plc.pnow(0) > 1_00, 10, "moving")
    before = len(emu.bus_changes(0))
    time.sleep(2.0)  # silence: no request at all
    stops = [c for c in emu.bus_changes(0)[before:] if c[2] == "CancelMotion"]
    assert stops, f"a stop went out: {emu.bus_changes(0)[before:]}"
    latched, count = plc.read(GATEWAY_UNIT, G_FAILSAFE, 2)
    # At least this trip; a host stall of QEMU longer than 500 ms while the PLC polled may have
    # tripped it once more (the firmware cannot tell a stalled emulator from a silent PLC).
    assert latched == 1 and count >= 2, ("latched, counted", latched, count)
    at = plc.pnow(0)
    time.sleep(0.3)  # (less than the watchdog: another silence would trip it again)
    assert plc.pnow(0) == at < 70_00, "stopped short of the target"
    assert plc.cmst(0) == (FAILED, REASON_CANCELLED << 8)
    plc.write(GATEWAY_UNIT, G_FAILSAFE, 0)
    assert plc.read(GATEWAY_UNIT, G_FAILSAFE, 2) == [0, count]


def test_malformed_and_out_of_range_requests_get_exceptions_and_never_reach_the_bus(emu):
    plc = online(emu)
    plc.home(0)
    # Frames that are not valid requests (bad CRC, garbage, another unit) are no sign of life:
    # a long enough run of them trips the PLC watchdog, which stops every axis. Not here.
    plc.write(GATEWAY_UNIT, G_WATCHDOG, 10_000)
    time.sleep(0.3)
    before = emu.bus_changes()
    u = unit(0)
    cases = [
        ("read 0x1234", lambda: plc.read(u, 0x1234), ILLEGAL_DATA_ADDRESS),
        ("write 0x1234", lambda: plc.write(u, 0x1234, 1), ILLEGAL_DATA_ADDRESS),
        ("coil 0x0404", lambda: plc.coil(u, 0x0404, True), ILLEGAL_DATA_ADDRESS),
        ("POSR 16", lambda: plc.write(u, POSR, 16), ILLEGAL_DATA_VALUE),
        ("beyond stroke", lambda: plc.direct(0, 100_01), ILLEGAL_DATA_VALUE),
        ("zero speed", lambda: plc.direct(0, 10_00, speed=0), ILLEGAL_DATA_VALUE),
        ("watchdog 10", lambda: plc.write(GATEWAY_UNIT, G_WATCHDOG, 10), ILLEGAL_DATA_VALUE),
        ("sync unknown axis", lambda: plc.write(GATEWAY_UNIT, G_SYNC_MASK, 0b10), ILLEGAL_DATA_VALUE),
        (
            "FC16 mask write",
            lambda: plc.call("mask_write_register", address=DRG1, and_mask=0, or_mask=DRG1_SON, unit=u),
            ILLEGAL_FUNCTION,
        ),
    ]
    for name, request, expected in cases:
        assert plc.exception(request) == expected, name
    # Raw frames: a bad CRC, garbage and another unit get no answer; malformed FC08/FC2B get
    # the spec's exceptions.
    good = adu(u, 0x03, 0x90, 0x05, 0x00, 0x01)
    assert plc.raw_exchange(good)[:3] == bytes([u, 3, 2])
    assert plc.raw_exchange(good[:-1] + bytes([good[-1] ^ 0xFF])) == b""
    assert plc.raw_exchange(bytes(range(0x20, 0x40))) == b""
    assert plc.raw_exchange(adu(unit(7), 0x03, 0x90, 0x05, 0x00, 0x01)) == b""
    assert plc.raw_exchange(adu(u, 0x2B, 0x0D, 0x01, 0x00))[:3] == bytes([u, 0xAB, ILLEGAL_FUNCTION])
    assert plc.raw_exchange(adu(u, 0x2B, 0x0E, 0x05, 0x00))[:3] == bytes([u, 0xAB, ILLEGAL_DATA_VALUE])
    assert plc.raw_exchange(adu(u, 0x08, 0x00))[:3] == bytes([u, 0x88, ILLEGAL_DATA_VALUE]), "FC08 short"
    assert plc.raw_exchange(adu(u, 0x08, 0x00, 0x15, 0, 0))[:3] == bytes([u, 0x88, ILLEGAL_FUNCTION])
    # FC08 echo and FC2B basic identification work.
    assert plc.raw_exchange(adu(u, 0x08, 0x00, 0x00, 0x12, 0x34)) == adu(u, 0x08, 0x00, 0x00, 0x12, 0x34)
    # Regular identification names the board the firmware was built for.
    ident = plc.raw_exchange(adu(GATEWAY_UNIT, 0x2B, 0x0E, 0x02, 0x00))
    assert ident[:4] == bytes([GATEWAY_UNIT, 0x2B, 0x0E, 0x02]) and b"STM32L475VG" in ident, ident
    time.sleep(0.3)
    assert emu.bus_changes() == before, "nothing but polls reached the bus"
    assert plc.read(u, DRG1) == [DRG1_SON], "state untouched"
    assert plc.read(u, POSR) == [0]


@pytest.mark.axes("0-1")
def test_a_cut_axis_goes_offline_the_others_carry_on_and_it_rejoins(emu):
    """A wire to one controller cut (rc-sim: the axis stops answering): the gateway reports it
    offline (LINK 2, its link output and bus LED state) within the retries' bound, keeps serving
    the other axis, and takes the axis back on its own once it answers again."""
    plc = online(emu, 0)
    # The firmware's defaults enable axis 0 only: commission axis 1 as a PLC would (AXISCFG
    # enable, APPLY: a new establishment with both axes).
    plc.write(GATEWAY_UNIT, AXISCFG + 8 * 1, 1)
    wait_for(lambda: _apply(plc), 10, "APPLY taken (refused with 03 while the bus is busy)")
    wait_for(lambda: plc.read(unit(1), LINK)[0] == LINK_ONLINE, 30, "axis 1 online after APPLY")
    emu.inject("silent 1 on")
    wait_for(lambda: plc.read(unit(1), LINK)[0] == LINK_OFFLINE, 10, "axis 1 offline")
    assert plc.read(unit(0), LINK)[0] == LINK_ONLINE
    before = plc.read(unit(0), CMCT)[0]
    plc.servo_on(0)
    assert plc.read(unit(0), CMCT)[0] == before + 1, "axis 0 still takes commands"
    # A command for the offline axis is refused at once (04), never queued to run later.
    with pytest.raises(ModbusError) as refused:
        plc.write(unit(1), DRG1, [DRG1_SON])
    assert refused.value.code == SERVER_FAILURE
    emu.inject("silent 1 off")
    # The rejoin try comes within the engine's rejoin interval (5 s) plus a cycle.
    wait_for(lambda: plc.read(unit(1), LINK)[0] == LINK_ONLINE, 30, "axis 1 back online")
    assert not [c for c in emu.bus_changes(1) if c[2] in ("ServoOn", "Servo")], "nothing ran late on axis 1"
