"""Every exception without a handler of its own, on the real firmware: an NMI and an interrupt that
no driver binds both run the firmware's `DefaultHandler` (src/rt.rs), which forces every output
OFF, the alarm LED on and both RS485 drivers released (the same as a HardFault), and then resets
the chip. cortex-m-rt's own default handler spun there with the outputs as they were, until the
watchdog fired up to 1.3 s later.

The emulator build holds the handler after the outputs are safe until the harness has read the
pins (`Emulator.release_fault`), then resets; QEMU keeps no reset flags (RESETCAUSE reads power-on
after any reset there), so the restart shows in the log: a second start, and the PLC line answers
again.
"""

import pytest

from emu import Emulator
from plc import GATEWAY_UNIT, G_VERSION, crc16, wait_for

from test_firmware import assert_safe_and_halted, outputs_on


def starts(emu):
    return sum("INFO  ready" in line for line in emu.log())


def answers(emu):
    """The gateway unit answers a read of VERSION (raw: the probe that went unanswered during the
    hold may be answered late, after the restart, and `raw_exchange` drains that first)."""
    request = bytes([GATEWAY_UNIT, 3, G_VERSION >> 8, G_VERSION & 0xFF, 0, 2])
    reply = emu.plc.raw_exchange(request + crc16(request), wait=1.0)
    return reply[:3] == bytes([GATEWAY_UNIT, 3, 4])


@pytest.mark.parametrize("fault, exception", [(Emulator.NMI, 2), (Emulator.UNBOUND_IRQ, 16 + 76)],
                         ids=["nmi", "unbound_interrupt"])
def test_a_fault_without_a_handler_forces_the_outputs_off_then_restarts(emu, fault, exception):
    outputs_on(emu)
    assert starts(emu) == 1
    emu.request_fault(fault)
    line = emu.wait_log("has no handler", 5)
    # SWPMI1 is interrupt 76: exception 92.
    assert f"exception {exception} has no handler" in line, line
    # Held in the handler: outputs OFF, alarm LED on, both drivers released, nothing served.
    assert_safe_and_halted(emu)
    emu.release_fault()
    wait_for(lambda: starts(emu) == 2, 20, "a second start")
    assert not any("watchdog" in line for line in emu.log()), "reset by the handler, not the watchdog"
    wait_for(lambda: answers(emu), 10, "the PLC line answers again")
