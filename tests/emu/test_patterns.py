"""PIO patterns 4 and 5 (IAI's solenoid valve modes 1 and 2) and 1 (teaching) on the real
firmware ELF in QEMU, driven through the pins as a PLC wired for them drives them: the pattern is
chosen over Modbus (PIOPAT, PIOSTART) with the point table; then ST inputs move the axis and
PE0-PE6 or LS0-LS2 answer, or MODE, the JOG inputs and PWRT teach a point.

Patterns 4 and 1 need ports no connector of the L475 board has left (IN6-IN9, OUT4, OUT5,
OUT9): the emulator build has them on port E (src/board/l475.rs), and these tests use them.
"""

import time

import pytest

from emu import ALM_N, CSTR, MOVE, PEND, RES
from plc import (
    FAILED, G_PIO_PATTERN, G_PIO_START, GATEWAY_UNIT, LINK, LINK_ONLINE, REASON_PIO_INPUT, unit,
    wait_for,
)
from test_discrete import (
    commissioned, output, pulses_during_bus_traffic, servo_on_and_homed, wait_output,
)


def moves(emu):
    return [c for c in emu.bus_changes(0) if c[2] == "MoveToPoint"]


def in_pattern(emu, pins, pattern, start):
    """PIOPAT and PIOSTART written, read back; servo on and homed through the pins."""
    plc = emu.plc
    plc.write(GATEWAY_UNIT, G_PIO_PATTERN, pattern)
    plc.write(GATEWAY_UNIT, G_PIO_START, start)
    assert plc.read(GATEWAY_UNIT, G_PIO_PATTERN, 2) == [pattern, start]
    servo_on_and_homed(emu, pins)


def test_pattern_5_reed_switches_show_where_the_axis_is_however_it_got_there(emu):
    # Point 0 the rear end, 1 the front end, 2 the intermediate point (band 0.10 mm).
    pins = commissioned(emu, {0: (5_00, 100_00), 1: (70_00, 100_00), 2: (40_00, 100_00)})
    in_pattern(emu, pins, 5, 1)  # edge
    plc = emu.plc
    # Homed at 0 mm: within no point's band.
    wait_for(lambda: emu.outputs() & 0x7 == 0, 5, "no reed switch at 0 mm")
    for st in (1, 0, 2):
        pins.pulse(st, 0.05)
        wait_for(lambda: emu.outputs() & 0x7 == 1 << st, 15, f"LS{st} only")
        wait_output(emu, PEND, 1, 5, "PEND")
    assert len(moves(emu)) == 3
    # A move commanded over Modbus, no ST input: the switch of where it ends, as a cylinder's.
    plc.direct(0, 70_00)
    wait_for(lambda: emu.outputs() & 0x7 == 0b010, 15, "LS1 after a Modbus move to 70 mm")
    plc.direct(0, 55_00)
    wait_for(lambda: abs(plc.pnow(0) - 55_00) <= 10, 15, "at 55 mm")
    wait_for(lambda: emu.outputs() & 0x7 == 0, 5, "no switch between the points")
    assert len(moves(emu)) == 3, "no PIO move"
    # ST3 and up are no inputs of pattern 5: nothing moves.
    pins.pulse(3, 0.05)
    time.sleep(0.5)
    assert len(moves(emu)) == 3


def test_pattern_4_level_release_mid_move_stops_and_two_st_inputs_are_refused(emu):
    pins = commissioned(emu, {3: (70_00, 20_00), 5: (30_00, 100_00), 6: (50_00, 100_00)})
    in_pattern(emu, pins, 4, 0)  # level, PCON's default
    plc = emu.plc
    # ST3 held: to 70 mm at 20 mm/s (3.5 s); released after about a second.
    pins.set(3, True)
    wait_for(lambda: len(moves(emu)) == 1, 5, "the move to point 3")
    time.sleep(1.0)
    before = len(emu.bus_changes(0))
    pins.set(3, False)
    wait_for(lambda: "CancelMotion" in [c[2] for c in emu.bus_changes(0)[before:]], 5, "the stop")
    time.sleep(0.5)
    stopped = plc.pnow(0)
    assert 5_00 < stopped < 65_00, f"stopped short, at {stopped / 100} mm"
    assert emu.outputs() & 0x7F == 0 and output(emu, PEND) == 0, "not complete: no PE3, no PEND"
    # Held until it gets there: PE3.
    pins.set(3, True)
    wait_for(lambda: emu.outputs() & 0x7F == 1 << 3, 15, "PE3")
    pins.set(3, False)
    time.sleep(0.1)
    assert emu.outputs() & 0x7F == 1 << 3, "released at its point: PE3 stays"
    # ST5 and ST6: PE5 (OUT5) and ST6 (IN6) on the ports only the emulator build has.
    for st in (5, 6):
        pins.set(st, True)
        wait_for(lambda: emu.outputs() & 0x7F == 1 << st, 15, f"PE{st}")
        pins.set(st, False)
    # Two ST inputs at once: refused, as IAI's alarm 085: *ALM OFF, no PE, CMST 3 with the
    # inputs, nothing sent.
    count = len(moves(emu))
    pins.set(3, True)
    pins.set(5, True)
    wait_output(emu, ALM_N, 0, 5, "*ALM OFF")
    assert emu.outputs() & 0x7F == 0
    assert plc.cmst(0) == (FAILED, REASON_PIO_INPUT << 8 | 1 << 3 | 1 << 5)
    pins.set(5, False)
    time.sleep(0.3)
    assert len(moves(emu)) == count, "nothing moved, nor after one of them is released"
    pins.set(3, False)
    pins.pulse(RES, 0.05)
    wait_output(emu, ALM_N, 1, 5, "*ALM ON after RES")
    pins.set(5, True)
    wait_for(lambda: emu.outputs() & 0x7F == 1 << 5, 15, "PE5 again")


def test_a_pattern_the_gateway_lacks_is_refused(emu):
    """PIOPAT values other than 0, 1, 4 and 5 answer exception 03, and PIOPAT stays. (A pattern
    whose ports the board lacks is refused the same way: tests/tests/gateway_sim, with the
    board's ports restricted, since the emulator build has them all.)"""
    plc = emu.plc
    wait_for(lambda: plc.read(unit(0), LINK)[0] == LINK_ONLINE, 20, "axis 0 online")
    for bad in (2, 3, 6, 0xFFFF):
        assert plc.exception(plc.write, GATEWAY_UNIT, G_PIO_PATTERN, bad) == 3
    assert plc.read(GATEWAY_UNIT, G_PIO_PATTERN) == [0]


@pytest.mark.axes("0-3")
def test_an_st_pulse_just_above_the_debounce_is_taken_whatever_the_bus_does(emu):
    """Pattern 5 in edge mode, 8 ms pulses on ST0 and ST1 in turn during bus traffic: as CSTR's
    in pattern 0 (test_discrete), every pulse the firmware sampled for the debounce time moves
    the axis, whatever the bus and the PLC line are doing."""
    pins = commissioned(emu, {0: (20_00, 200_00), 1: (22_00, 200_00)})
    emu.plc.write(GATEWAY_UNIT, G_PIO_PATTERN, 5)
    emu.plc.write(GATEWAY_UNIT, G_PIO_START, 1)

    def strobe(n):
        st = n % 2
        pins.pulse(st, 0.008)
        return lambda: emu.outputs() & 0x7 == 1 << st

    pulses_during_bus_traffic(emu, pins, 0b11, strobe, count=12)


MODE, JISL, JOG_PLUS, JOG_MINUS, MODES = 6, 7, 8, 9, 9  # inputs IN6-IN9; MODES is OUT9
ROW = 0x1000


def stored_row(plc, n):
    """Row n's PCMD (0.01 mm) and VCMD (0.01 mm/s), once readable (04 while it is fetched)."""
    def read():
        try:
            return plc.read(unit(0), ROW + 16 * n, 6)
        except Exception:
            return None

    row = wait_for(read, 10, f"row {n} readable")
    return row[0] << 16 | row[1], row[4] << 16 | row[5]


def at_rest(plc):
    """The position once two reads 0.3 s apart agree (0.01 mm)."""
    def settled():
        first = plc.pnow(0)
        time.sleep(0.3)
        return first if plc.pnow(0) == first else None

    return wait_for(settled, 10, "the axis at rest")


def test_pattern_1_a_jog_and_a_pwrt_whose_row_reads_back(emu):
    pins = commissioned(emu, {})
    in_pattern(emu, pins, 1, 0)
    plc = emu.plc
    pins.set(MODE, True)
    wait_output(emu, MODES, 1, 5, "MODES")
    # JOG+ held 0.4 s at 100 mm/s (PIOJOG's default), released: the axis stops.
    pins.set(JOG_PLUS, True)
    wait_output(emu, MOVE, 1, 5, "jogging")
    time.sleep(0.4)
    pins.set(JOG_PLUS, False)
    wait_output(emu, MOVE, 0, 5, "stopped on release")
    at = at_rest(plc)
    assert 5_00 < at < 70_00, f"jogged to {at / 100} mm"
    # PWRT into point 9, which holds nothing: WEND; the row reads back the position, with the
    # jog speed.
    pins.select(9)
    time.sleep(0.05)
    pins.set(CSTR, True)  # PWRT
    wait_output(emu, PEND, 1, 10, "WEND")
    assert stored_row(plc, 9) == (at, 100_00)
    pins.set(CSTR, False)
    wait_output(emu, PEND, 0, 5, "WEND OFF with PWRT")
    # JISL: one 0.10 mm step toward home per JOG- edge.
    pins.set(JISL, True)
    pins.pulse(JOG_MINUS, 0.05)
    stepped = at_rest(plc)
    assert abs(stepped - (at - 10)) <= 1, f"{at} -> {stepped}: 0.10 mm, to the 0.01 mm shown"
    # Out of teaching mode, CSTR with PC = 9 moves to the point taught.
    pins.set(MODE, False)
    wait_output(emu, MODES, 0, 5, "MODES OFF")
    pins.pulse(CSTR)
    wait_for(lambda: output(emu, PEND) == 1 and emu.outputs() & 0xF == 9, 15, "at point 9")
    assert abs(at_rest(plc) - at) <= 10, "within the point's band (0.10 mm)"
