"""The firmware itself in QEMU: it boots, its task runs, and on a panic or a stack overflow (a
HardFault) the outputs go to their safe state (every PIO output OFF, the alarm LED on, both RS485
drivers released) before anything else, and it stays halted."""

import re

from emu import BUS_DE, BUS_TX, INPUTS, LED_ALARM, LED_RUN, MODE_AF, MODE_OUTPUT, OUTPUTS, PLC_DE, STOP_INPUT
from plc import LINK, LINK_ONLINE, unit, wait_for

SON, STP_N = 15, 12
SV, LINK_OUT = 12, 13


def test_boots_and_blinks_the_run_led(emu):
    assert any("rc-gateway" in line and "starting" in line for line in emu.log())
    first = emu.odr(LED_RUN)
    wait_for(lambda: emu.odr(LED_RUN) != first, 3, "the run LED toggles")
    # The gateway task keeps running: it toggles again.
    wait_for(lambda: emu.odr(LED_RUN) == first, 3, "the run LED toggles back")


def outputs_on(emu):
    """The stop chain closed, *STP and SON on the wire-driven axis 0: until SV and LINK are ON
    (outputs a fault must turn OFF)."""
    emu.set_pin(STOP_INPUT, True)
    emu.set_pin(INPUTS[STP_N], True)
    emu.set_pin(INPUTS[SON], True)
    wait_for(lambda: emu.plc.read(unit(0), LINK)[0] == LINK_ONLINE, 20, "axis 0 online")
    wait_for(lambda: emu.outputs() >> SV & 1 and emu.outputs() >> LINK_OUT & 1, 10, "SV and LINK on")


def assert_safe_and_halted(emu):
    """After a fault: every output OFF, the alarm LED on, both drivers released; halted: nothing
    more goes out on the bus, no Modbus answer."""
    assert emu.outputs() == 0, f"every output OFF: {emu.outputs():#06x}"
    assert emu.odr(LED_ALARM) == 1
    for de in (BUS_DE, PLC_DE):
        assert (emu.mode(de), emu.odr(de)) == (MODE_OUTPUT, 0), f"DE {de} released"
    sent = len(emu.bus_commands())
    assert emu.plc.raw_exchange(bytes([1, 3, 0x90, 0x05, 0, 1, 0xB9, 0x0B]), wait=0.5) == b""
    assert len(emu.bus_commands()) == sent


def test_panic_leaves_outputs_safe_and_drivers_off(emu):
    outputs_on(emu)
    emu.request_panic()
    emu.wait_log("panic at", 5)
    assert_safe_and_halted(emu)
    assert set(OUTPUTS) >= {SV, LINK_OUT}


def test_stack_overflow_faults_and_leaves_outputs_safe(emu):
    # flip-link's layout: the stack at the bottom of RAM, the statics above it. An overflow runs off
    # the start of RAM and faults there; the HardFault entry moves to a stack of its own (the core
    # could not stack its frame below RAM), and the handler, whose masks are statics the overflow
    # did not reach, forces the outputs safe. In the emulator build it then halts rather than
    # ending QEMU, so that the pins can be read.
    outputs_on(emu)
    emu.request_stack_overflow()
    line = emu.wait_log("HardFault", 5)
    assert "stack overflow" in line, line
    sp = int(re.search(r"sp (0x[0-9a-f]+)", line).group(1), 16)
    bottom = emu.symbols["_stack_end"]
    assert sp < bottom, f"faulted below the start of RAM ({bottom:#x}): sp {sp:#x}"
    # The painted stack region used to within one recursion level (512 bytes) of its bottom.
    room = emu.symbols["_stack_start"] - bottom
    assert emu.stack_high_water_mark() > room - 1024, "the stack ran down to the bottom of RAM"
    assert_safe_and_halted(emu)
    # Halted, not locked up or reset: QEMU runs on.
    emu._check_alive("halted after the HardFault")


def test_the_establishment_break_holds_tx_low_with_the_driver_on(emu):
    # The break follows start-up (§6-1 step 1: 200 ms or more). A pseudo-terminal cannot carry
    # it (rc-sim takes the switch to 9600 bit/s before it as the break): the pins show it.
    def in_break():
        return (emu.mode(BUS_TX), emu.odr(BUS_TX), emu.mode(BUS_DE), emu.odr(BUS_DE)) == (
            MODE_OUTPUT, 0, MODE_OUTPUT, 1)

    wait_for(in_break, 2, "TX held low by a GPIO, DE driven high", interval=0.002)
    wait_for(lambda: emu.mode(BUS_TX) == MODE_AF and emu.mode(BUS_DE) == MODE_AF, 3,
             "TX and DE back to the UART", interval=0.005)
    wait_for(lambda: any(c[2] == "SetResponseDelay" for c in emu.bus_commands(0)), 5,
             "the first command after the break")
