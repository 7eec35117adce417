"""Stops on the real firmware ELF in QEMU (issue 33): a stop is never refused, lost or late.

- A stop that gets no answer is owed, not given up: with the wire to a moving axis cut (rc-sim's
  `cut 0 on`: the controller hears nothing, answers nothing and goes on moving), each face of a
  stop (a Modbus DRG1 STP write, the STOP coil, the stop input, the PIO's *STP, a jog's release
  in pattern 1) leaves the axis owed it (LINK 3); every frame the gateway sends the axis
  meanwhile is `d`, so once the wire is mended the first command the controller hears is its
  stop, and the axis ends at rest.
- The hand-over: a commissioning PC arms the PLC watchdog and is unplugged; the watchdog trips
  (a stop to every axis, *ALM OFF) and the master stays silent for good. A RES pulse on the
  discrete inputs acknowledges the latch all the same and disarms the watchdog, and the machine
  runs by its wires alone. (Before issue 33 the RES pulse was refused while the silence lasted:
  such a machine stayed latched until a power cycle.)

The PIO's *STP with a cut wire: its stop, repeated every 100 ms while the axis last reported
moving, used to supersede the unanswered one before its resends ran out, so the axis was never
found offline nor owed and, a fresh first stop always waiting, the other axes got no frame at all
while *STP stayed OFF (found by these tests). A repeated stop now takes over the tries of the one
it supersedes (`Engine::submit`): both cases below pass.

The controllers' view is rc-sim's log: its `where` control notes the simulated axis' own
position and motion, its control notes (`-- control: Cut(Axis(0), false)`) mark when the wire
was mended, and the frames logged after that note are the ones the controller heard. QEMU is
slow and loosely timed: the tests check behaviour and order with generous limits, never timing.
"""

import re
import time

import pytest

from emu import ALM_N, CSTR, HEND, HOME, MOVE, PEND, RES, SON, STOP_INPUT, STP_N, SV, Pins
from plc import (
    COIL_STOP, DONE, DRG1, DRG1_SON, DRG1_STP, G_BUS_STOPS_OWED, G_FAILSAFE, G_PIO_AXIS, G_PIO_JOG,
    G_PIO_PATTERN, G_WATCHDOG, GATEWAY_UNIT, LINK, LINK_OFFLINE, LINK_ONLINE, LINK_OWED, ModbusError,
    unit, wait_for,
)
from test_discrete import output, servo_on_and_homed, wait_output

MODE, JOG_PLUS, MODES = 6, 8, 9  # pattern 1: IN6 MODE, IN8 JOG+; OUT9 MODES
ROW = 0x1000
AXISCFG, APPLY = 0x0100, 0x000A  # gateway unit: axis n's configuration at 0x0100 + 8 n; APPLY
TARGET = 70_00  # 0.01 mm: within the simulated actuator's stroke
SLOW = 1_00  # 0.01 mm/s: 70 s to the target, far longer than a test


# ---------------------------------------------------------------------- rc-sim's log


def requests(lines, axis=0):
    """(line index, command name) of every request to `axis` in rc-sim's log lines."""
    found = []
    for i, line in enumerate(lines):
        m = re.match(r"\s*[\d.]+ >> Request \{ axis: Axis\((\d+)\), command: (\w+)", line)
        if m and int(m.group(1)) == axis:
            found.append((i, m.group(2)))
    return found


def replies(lines, axis=0):
    """(line index, echoed command) of every reply from `axis` in rc-sim's log lines."""
    found = []
    for i, line in enumerate(lines):
        m = re.match(r"\s*[\d.]+ << \w+ \{ axis: Axis\((\d+)\), code: (\w+)", line)
        if m and int(m.group(1)) == axis:
            found.append((i, m.group(2)))
    return found


def where(emu, axis=0):
    """The simulated axis' own state, as rc-sim's `where` notes it: {position, target (pulses),
    moving, homing, pfin}."""
    pattern = re.compile(
        rf"-- where: axis {axis} position (-?\d+) target (-?\d+) moving (\w+) homing (\w+) pfin (\w+)")

    def notes():
        return [m for m in map(pattern.search, emu.sim_log()) if m]

    before = len(notes())
    emu.inject(f"where {axis}")
    note = wait_for(lambda: (lambda n: n[-1] if len(n) > before else None)(notes()), 10, "rc-sim's where")
    position, target, moving, homing, pfin = note.groups()
    return {"position": int(position), "target": int(target), "moving": moving == "true",
            "homing": homing == "true", "pfin": pfin == "true"}


# ---------------------------------------------------------------------- the gateway


def link(plc, axis=0):
    return plc.read(unit(axis), LINK)[0]


def stops_owed(plc):
    hi, lo = plc.read(GATEWAY_UNIT, G_BUS_STOPS_OWED, 2)
    return hi << 16 | lo


def commissioned(emu, pio_axis):
    """The cabinet as wired (stop chain closed; with the PIO, *STP and SON ON), the stop input's
    power-up latch acknowledged, the axis online, the watchdog off (a host stall of QEMU must not
    trip it here), PIOAXIS 0 or none."""
    plc = emu.plc
    emu.set_pin(STOP_INPUT, True)
    pins = Pins(emu)
    if pio_axis:
        pins.set(STP_N, True)
        pins.set(SON, True)
    wait_for(lambda: plc.read(GATEWAY_UNIT, G_FAILSAFE)[0] & 2, 5, "the stop input's power-up latch")
    plc.acknowledge()
    wait_for(lambda: link(plc) == LINK_ONLINE, 30, "axis 0 online")
    plc.write(GATEWAY_UNIT, G_WATCHDOG, 0)
    plc.write(GATEWAY_UNIT, G_PIO_AXIS, 0 if pio_axis else 0xFFFF)
    return plc, pins


def direct_move(emu, plc):
    """A long slow direct move over Modbus, seen under way on the simulated axis."""
    plc.direct(0, TARGET, speed=SLOW, accel=30)
    wait_for(lambda: plc.pnow(0) > 20, 15, "moving (PNOW)")


class Face:
    """One face of a stop: how the axis is set moving, and how the stop is given."""

    pio_axis = False

    def start(self, emu):
        plc, pins = commissioned(emu, self.pio_axis)
        self.plc, self.pins = plc, pins
        self.prepare(emu)
        self.move(emu)

    def prepare(self, emu):
        self.plc.home(0)

    def move(self, emu):
        direct_move(emu, self.plc)

    def stop(self, emu):
        raise NotImplementedError


class Drg1Stp(Face):
    def stop(self, emu):
        self.plc.write(unit(0), DRG1, DRG1_SON | DRG1_STP)


class StopCoil(Face):
    def stop(self, emu):
        self.plc.coil(unit(0), COIL_STOP, True)


class StopInput(Face):
    def stop(self, emu):
        emu.set_pin(STOP_INPUT, False)  # the stop chain opens


class PioStp(Face):
    pio_axis = True

    def prepare(self, emu):
        servo_on_and_homed(emu, self.pins)

    def stop(self, emu):
        self.pins.set(STP_N, False)


class JogRelease(Face):
    """Pattern 1: JOG+ held at 1 mm/s (PIOJOG), released while the wire is cut."""

    pio_axis = True

    def prepare(self, emu):
        self.plc.write(GATEWAY_UNIT, G_PIO_PATTERN, 1)
        self.plc.write(GATEWAY_UNIT, G_PIO_JOG, SLOW)
        assert self.plc.read(GATEWAY_UNIT, G_PIO_JOG) == [SLOW]
        servo_on_and_homed(emu, self.pins)

    def move(self, emu):
        self.pins.set(MODE, True)
        wait_output(emu, MODES, 1, 10, "MODES: teaching mode")
        self.pins.set(JOG_PLUS, True)
        wait_output(emu, MOVE, 1, 10, "jogging")
        wait_for(lambda: self.plc.pnow(0) > 20, 15, "moving (PNOW)")

    def stop(self, emu):
        self.pins.set(JOG_PLUS, False)


FACES = {
    "drg1_stp": Drg1Stp,
    "stop_coil": StopCoil,
    "stop_input": StopInput,
    "pio_stp": PioStp,
    "jog_release": JogRelease,
}


def cases():
    for face in FACES:
        for when in ("at_once", "once_offline"):
            yield pytest.param(face, when, id=f"{face}-{when}")


@pytest.mark.parametrize("face, when", cases())
def test_a_stop_the_cut_wire_swallows_is_owed_and_is_the_first_frame_after_the_mend(emu, face, when):
    """`when`: the stop given right after the cut (the axis still online: the stop is sent and
    goes unanswered), or once the gateway has found the axis offline (LINK 2: the stop is taken
    all the same, never refused)."""
    given = FACES[face]()
    given.start(emu)
    plc = given.plc
    moving = where(emu)
    assert moving["moving"], "the simulated axis moves"
    owed_before = stops_owed(plc)

    emu.inject("cut 0 on")
    if when == "once_offline":
        wait_for(lambda: link(plc) == LINK_OFFLINE, 30, "LINK 2: the axis offline")
        assert where(emu)["moving"], "the simulated axis moves on"
    given.stop(emu)  # a Modbus face raises if refused
    # The stop goes unanswered through its resends: owed (LINK 3), counted.
    wait_for(lambda: link(plc) == LINK_OWED, 30, "LINK 3: offline and owed a stop")
    owed_from = len(emu.sim_log())
    assert stops_owed(plc) == owed_before + 1, "BUS counts the stop owed"
    # The controller heard nothing: it goes on moving.
    first = where(emu)
    time.sleep(0.5)
    second = where(emu)
    assert first["moving"] and second["moving"], (first, second)
    assert second["position"] != first["position"], ("still moving", first, second)
    # Whatever the gateway sends the axis meanwhile (probes, rejoin tries) goes out as `d`.
    wait_for(lambda: len(requests(emu.sim_log()[owed_from:])) >= 2, 20, "frames to the owed axis")
    assert link(plc) == LINK_OWED
    sent = [command for _, command in requests(emu.sim_log()[owed_from:])]
    assert set(sent) == {"CancelMotion"}, f"only d while owed: {sent}"

    emu.inject("cut 0 off")
    wait_for(lambda: link(plc) == LINK_ONLINE, 30, "LINK 1: the axis back")
    lines = emu.sim_log()
    mended = next(i for i, line in enumerate(lines) if "control: Cut(Axis(0), false)" in line)
    heard = requests(lines[mended:])
    answered = replies(lines[mended:])
    assert heard and heard[0][1] == "CancelMotion", f"the first command after the mend: {heard[:3]}"
    assert answered and answered[0][1] == "CancelMotion", f"the first reply after the mend: {answered[:3]}"
    # At rest, short of the target, where the stop caught it.
    wait_for(lambda: not where(emu)["moving"], 10, "the simulated axis at rest")
    rest = where(emu)
    time.sleep(0.5)
    assert where(emu)["position"] == rest["position"], "standing still"
    assert rest["position"] != moving["target"], "stopped short of the target"
    assert 0 < plc.pnow(0) < TARGET
    assert stops_owed(plc) == owed_before + 1, "no other stop was owed"


@pytest.mark.axes("0-1")
def test_a_cut_pio_axis_held_by_stp_leaves_the_bus_to_the_other_axes(emu):
    """The same cut under *STP (the PIO axis' wire cut mid-move, *STP OFF and held OFF): the
    other axis must keep its share of the bus (polls, and a command over Modbus runs), as with
    any other face of the stop."""
    given = PioStp()
    given.plc, given.pins = commissioned(emu, True)
    plc = given.plc
    plc.write(GATEWAY_UNIT, AXISCFG + 8 * 1, 1)  # axis 1 enabled: APPLY re-establishes the bus

    def applied():
        try:
            plc.write(GATEWAY_UNIT, APPLY, 1)
            return True
        except ModbusError:  # 03 while the bus is busy
            return False

    wait_for(applied, 20, "APPLY taken")
    wait_for(lambda: link(plc, 0) == LINK_ONLINE and link(plc, 1) == LINK_ONLINE, 30, "both axes online")
    given.prepare(emu)
    given.move(emu)
    emu.inject("cut 0 on")
    given.stop(emu)
    time.sleep(1.0)
    cut_from = len(emu.sim_log())
    plc.write(unit(1), DRG1, DRG1_SON)
    # Well past the stop's resends (1 + 2 of about 0.3 s each in QEMU).
    wait_for(lambda: len(requests(emu.sim_log()[cut_from:], axis=1)) >= 3, 10, "frames to axis 1")
    assert plc.settle(1) == (DONE, 0), "axis 1's servo on ran"
    wait_for(lambda: link(plc, 0) == LINK_OWED, 10, "axis 0 owed its stop")


# ---------------------------------------------------------------------- the hand-over


def test_a_res_pulse_clears_the_watchdog_a_commissioning_pc_left_behind(emu):
    """Commissioned over Modbus (point 3, PIOAXIS 0, the watchdog at its default 1000 ms, which
    the master's requests arm); the PC unplugged: the watchdog trips and the silence never
    ends. One RES pulse acknowledges it and disarms the watchdog, and the wires run the machine:
    HOME and a CSTR move the axis. Nothing is read over Modbus between the PC leaving and the
    end (a request would re-arm the watchdog)."""
    plc = emu.plc
    # The cabinet's wires: stop chain closed, *STP ON, SON ON.
    emu.set_pin(STOP_INPUT, True)
    pins = Pins(emu)
    pins.set(STP_N, True)
    pins.set(SON, True)
    # Commissioning: the watchdog off while it lasts (a host stall of QEMU must not trip it);
    # back to 1000 ms as the last write.
    wait_for(lambda: plc.read(GATEWAY_UNIT, G_FAILSAFE)[0] & 2, 5, "the stop input's power-up latch")
    plc.write(GATEWAY_UNIT, G_WATCHDOG, 0)
    plc.acknowledge()
    wait_for(lambda: link(plc) == LINK_ONLINE, 30, "axis 0 online")
    plc.write(GATEWAY_UNIT, G_PIO_AXIS, 0)
    values = [30_00 >> 16, 30_00 & 0xFFFF, 0, 10, 0, 50_00, 0, 0, 0, 0, 30, 30, 0, 0, 0]
    plc.write(unit(0), ROW + 16 * 3, values)

    def stored():
        try:
            return plc.read(unit(0), ROW + 16 * 3, 6) == values[:6]
        except Exception:  # 04 while the row is fetched
            return False

    wait_for(stored, 10, "row 3 stored")
    wait_output(emu, SV, 1, 10, "SV: SON")
    assert plc.read(GATEWAY_UNIT, G_FAILSAFE) == [0]
    plc.write(GATEWAY_UNIT, G_WATCHDOG, 1000)
    assert plc.read(GATEWAY_UNIT, G_WATCHDOG) == [1000]

    # The PC is unplugged: not one more request.
    silent_from = len(emu.bus_changes(0))
    wait_output(emu, ALM_N, 0, 10, "*ALM OFF: the watchdog tripped")
    assert emu.outputs() & 0xF == 1, "PM1-PM8 = FAILSAFE 1: the PLC watchdog"
    wait_for(lambda: "CancelMotion" in [c[2] for c in emu.bus_changes(0)[silent_from:]], 10, "its stop on the bus")
    # Held: the wires start nothing while it is latched.
    pins.pulse(HOME)
    time.sleep(1.0)
    assert "Home" not in [c[2] for c in emu.bus_changes(0)[silent_from:]], "held by the latch"
    assert output(emu, ALM_N) == 0

    # One RES pulse, the master still silent: acknowledged.
    pins.pulse(RES)
    wait_output(emu, ALM_N, 1, 10, "*ALM ON: acknowledged by RES while the master is silent")
    assert emu.outputs() & 0xF != 1
    # Disarmed: more silence than the watchdog's 1000 ms trips nothing.
    acknowledged = len(emu.bus_changes(0))
    time.sleep(2.5)
    assert output(emu, ALM_N) == 1, "not tripped again: the watchdog is disarmed"
    assert "CancelMotion" not in [c[2] for c in emu.bus_changes(0)[acknowledged:]], "no second stop"
    # The wires run the machine.
    pins.pulse(HOME)
    wait_output(emu, HEND, 1, 20, "HEND")
    assert "Home" in [c[2] for c in emu.bus_changes(0)[acknowledged:]]
    pins.select(3)
    time.sleep(0.05)
    pins.pulse(CSTR)
    wait_output(emu, PEND, 1, 20, "PEND at point 3")
    assert emu.outputs() & 0xF == 3, "PM1-PM8 show point 3"
    assert "MoveToPoint" in [c[2] for c in emu.bus_changes(0)[acknowledged:]]
    # Only now a master speaks again: FAILSAFE acknowledged, the trip counted.
    latched, count = plc.read(GATEWAY_UNIT, G_FAILSAFE, 2)
    assert latched == 0, "acknowledged by the RES pulse"
    assert count >= 2, "the stop input at power-up and the watchdog"
