"""The firmware's hardware layer, end to end in QEMU, through the bring-up node (src/bringup.rs):
boot, both lines both ways, bus rate changes, the break, PIO inputs to outputs, the stop input,
and the fail-safe after a panic."""

import time

import pytest

from conftest import (
    BUS_DE, BUS_TX, ESC, INPUTS, LED_ALARM, LED_LINK, LED_RUN, MODE_AF, MODE_OUTPUT, OUTPUTS,
    PLC_DE, STOP_INPUT, wait_for,
)

COMM_CHANGE = bytes([0x02] + [0x05] * 14 + [0x03])
ALL_INPUTS = sum(1 << bit for bit in INPUTS)
# The bring-up node mirrors INn to OUTn: the bits both words have.
MIRRORED = sum(1 << bit for bit in INPUTS if bit in OUTPUTS)


def test_boots_and_blinks_the_run_led(emu):
    assert any("rc-gateway" in line and "starting" in line for line in emu.log())
    first = emu.odr(LED_RUN)
    wait_for(lambda: emu.odr(LED_RUN) != first, 3, "the run LED toggles")
    # The gateway task keeps running: it toggles again.
    wait_for(lambda: emu.odr(LED_RUN) == first, 3, "the run LED toggles back")


def test_plc_frame_goes_to_the_bus(emu):
    frame = b"\x020n000000000082\x03"
    emu.plc_send(frame)
    assert emu.bus_receive(16) == frame


def test_bus_bytes_go_to_the_plc_and_light_the_link_led(emu):
    assert emu.odr(LED_LINK) == 0
    reply = b"\x02U0n0F0000B0035\x03"
    emu.bus_send(reply)
    assert emu.plc_receive(16) == reply
    wait_for(lambda: emu.odr(LED_LINK) == 1, 2, "link LED on")
    wait_for(lambda: emu.odr(LED_LINK) == 0, 3, "link LED off a second after the last byte")


def test_many_frames_both_ways_keep_their_order(emu):
    for i in range(20):
        frame = bytes([0x02]) + f"{i:02d}n0000000000{i % 10}".encode()[:14] + bytes([0x03])
        emu.plc_send(frame)
        assert emu.bus_receive(16) == frame
        answer = bytes([0x02]) + f"U{i:02d}00000000000".encode()[:14] + bytes([0x03])
        emu.bus_send(answer)
        assert emu.plc_receive(16) == answer


def test_a_partial_plc_frame_is_dropped_after_100_ms(emu):
    emu.plc_send(b"garbage")
    time.sleep(0.4)
    frame = b"\x02Xn000000000000\x03"
    emu.plc_send(frame)
    assert emu.bus_receive(16) == frame
    assert emu.quiet(0.3) == (b"", b"")


@pytest.mark.parametrize(
    "rate,termios_rate",
    [
        (38400, 38400),
        (115200, 115200),
        (19200, 19200),
        (57600, 57600),
        # No termios constant: QEMU picks the next one up (at or above 10/11 of the rate).
        (14400, 19200),
        (28800, 38400),
        (76800, 115200),
        (9600, 9600),
    ],
)
def test_bus_rate_change_reaches_the_line(emu, rate, termios_rate):
    assert emu.bus_speed() == 9600, "the bus starts at the rate after a break"
    emu.command(b"B" + str(rate).encode(), b"b")
    wait_for(lambda: emu.bus_speed() == termios_rate, 2, f"pty at {termios_rate}")
    # Bytes still flow both ways at the new rate.
    frame = b"\x020n000000000082\x03"
    emu.plc_send(frame)
    assert emu.bus_receive(16) == frame
    emu.bus_send(b"ok")
    assert emu.plc_receive(2) == b"ok"


def test_unknown_rate_and_command_are_refused(emu):
    emu.command(b"B12345", b"?")
    emu.command(b"Z", b"?")
    assert emu.bus_speed() == 9600
    assert emu.quiet(0.2)[0] == b""


def test_break_holds_tx_low_with_the_driver_enabled_then_releases(emu):
    assert (emu.mode(BUS_TX), emu.mode(BUS_DE)) == (MODE_AF, MODE_AF)
    started = time.monotonic()
    emu.command(b"K", b"K")
    # During the break: TX a GPIO output at 0, DE a GPIO output at 1 (transceiver driving).
    assert (emu.mode(BUS_TX), emu.odr(BUS_TX)) == (MODE_OUTPUT, 0)
    assert (emu.mode(BUS_DE), emu.odr(BUS_DE)) == (MODE_OUTPUT, 1)
    assert emu.plc_receive(2, timeout=3) == bytes([ESC]) + b"k"
    held = time.monotonic() - started
    # 200 ms in the guest; QEMU's icount clock follows real time loosely: bounds are generous.
    assert 0.15 <= held <= 2.0, held
    assert (emu.mode(BUS_TX), emu.mode(BUS_DE)) == (MODE_AF, MODE_AF)
    # The UART works again after the break.
    frame = b"\x020n000000000082\x03"
    emu.plc_send(frame)
    assert emu.bus_receive(16) == frame


def test_the_plc_line_is_served_during_a_break(emu):
    emu.command(b"K", b"K")
    emu.bus_send(b"x")  # what a controller could not send during a break; the bridge forwards it
    assert emu.plc_receive(1) == b"x"
    assert emu.plc_receive(2, timeout=3) == bytes([ESC]) + b"k"


def test_comm_change_frame(emu):
    emu.command(b"C", b"c")
    assert emu.bus_receive(16) == COMM_CHANGE


def test_each_input_drives_its_output(emu):
    emu.set_inputs(0)
    wait_for(lambda: emu.outputs() == 0, 2, "outputs off")
    for bit in INPUTS:
        emu.set_inputs(1 << bit)
        expected = (1 << bit) if bit in OUTPUTS else 0
        wait_for(lambda: emu.outputs() == expected, 2, f"IN{bit} -> outputs {expected:#06x}")
    emu.set_inputs(ALL_INPUTS)
    wait_for(lambda: emu.outputs() == MIRRORED, 2, "every mirrored output on")


def test_stop_input_off_turns_every_output_off_and_the_alarm_led_on(emu):
    emu.set_inputs(ALL_INPUTS, stop_released=True)
    wait_for(lambda: emu.outputs() != 0, 2, "outputs on")
    wait_for(lambda: emu.odr(LED_ALARM) == 0, 2, "alarm LED off")
    emu.set_pin(STOP_INPUT, False)
    wait_for(lambda: emu.outputs() == 0, 2, "outputs off on stop")
    wait_for(lambda: emu.odr(LED_ALARM) == 1, 2, "alarm LED on")
    emu.set_pin(STOP_INPUT, True)
    wait_for(lambda: emu.outputs() != 0, 2, "outputs back")


def test_the_stop_is_active_at_boot_until_the_stop_input_is_on(emu):
    # Nothing drives the stop input: its pull-down reads OFF, which is "stop".
    emu.set_pin(INPUTS[0], True)
    time.sleep(0.2)
    assert emu.outputs() == 0
    assert emu.odr(LED_ALARM) == 1


def test_panic_leaves_outputs_safe_and_drivers_off(emu):
    emu.set_inputs(ALL_INPUTS)
    wait_for(lambda: emu.outputs() == MIRRORED, 2, "every mirrored output on")
    emu.plc_send(bytes([ESC]) + b"P" + b" " * 14)
    emu.wait_log("panic at", 5)
    assert emu.outputs() == 0
    assert emu.odr(LED_ALARM) == 1
    for de in (BUS_DE, PLC_DE):
        assert (emu.mode(de), emu.odr(de)) == (MODE_OUTPUT, 0), f"DE {de} released"
    # Halted: no more bytes are moved.
    emu.plc_send(b"\x020n000000000082\x03")
    assert emu.quiet(0.3)[0] == b""
