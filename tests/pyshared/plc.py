"""A PLC's view of the gateway, shared by the end-to-end tests (tests/e2e: `rc-gateway-host` on a
pseudo-terminal) and the emulator tests (tests/emu: the real firmware in QEMU): the register map's
addresses and bits, and a Modbus RTU master (pymodbus, which nobody in this project wrote) with
the checked calls and axis helpers a PLC program would use.

Addresses and bits are those of protocol/src/plc/map.rs; README's register table is checked
against that file by tests/tests/readme.rs.
"""

import inspect
import time

from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusException

GATEWAY_UNIT = 63

# Axis registers.
PNOW, ALMC, DIPM, DOPM, DSS1, DSS2, DSSE = 0x9000, 0x9002, 0x9003, 0x9004, 0x9005, 0x9006, 0x9007
CMST, CMER, LINK, CMCT = 0x9F00, 0x9F01, 0x9F02, 0x9F03
DRG1, POSR, DIRECT = 0x0D00, 0x0D03, 0x9900
COIL_SON, COIL_ALRS, COIL_STP, COIL_HOME, COIL_STOP = 0x0403, 0x0407, 0x040A, 0x040B, 0x042C
DRG1_SON, DRG1_ALRS, DRG1_STP, DRG1_HOME, DRG1_CSTR = 1 << 12, 1 << 8, 1 << 5, 1 << 4, 1 << 3
DSS1_SV, DSS1_ALMH, DSS1_STP, DSS1_HEND, DSS1_PEND = 1 << 12, 1 << 10, 1 << 5, 1 << 4, 1 << 3
DOPM_ALM_N, DOPM_PEND, DOPM_HEND = 1 << 14, 1 << 11, 1 << 10
# Gateway unit.
G_VERSION, G_FAILSAFE, G_FAILSAFE_COUNT, G_WATCHDOG = 0x0000, 0x0004, 0x0005, 0x0006
G_SYNC_MASK, G_SYNC_START, G_SYNC_STATUS = 0x000B, 0x000C, 0x000D
G_PIO_AXIS, G_PIO_PATTERN, G_PIO_START, G_PIO_JOG = 0x000F, 0x001C, 0x001D, 0x001E
G_REQUEST, G_RESPONSE = 0x0200, 0x0210
G_BUS_STOPS_OWED = 0x0508  # BUS counters: stops owed (u32, high word first)
# CMST values and CMER reasons (protocol/src/plc/gateway.rs).
IDLE, TAKEN, DONE, FAILED = 0, 1, 2, 3
REASON_ALARM, REASON_CANCELLED, REASON_PAUSED, REASON_PIO_INPUT = 4, 6, 10, 13
# LINK values.
LINK_ONLINE, LINK_OFFLINE, LINK_OWED = 1, 2, 3
# Modbus exception codes.
ILLEGAL_FUNCTION, ILLEGAL_DATA_ADDRESS, ILLEGAL_DATA_VALUE, SERVER_FAILURE = 1, 2, 3, 4


def unit(axis):
    """Axis n is Modbus unit n + 1."""
    return axis + 1


class ModbusError(Exception):
    """An exception reply: `code` is the Modbus exception code."""

    def __init__(self, function, code):
        super().__init__(f"function {function:#04x}: exception {code:02d}")
        self.code = code


def _unit_keyword():
    """pymodbus renamed the unit keyword: `unit` (2.x), `slave` (3.0-3.8), `device_id` (3.9+)."""
    parameters = inspect.signature(ModbusSerialClient.read_holding_registers).parameters
    for name in ("device_id", "slave", "unit"):
        if name in parameters:
            return name
    raise RuntimeError(f"unknown pymodbus API: {list(parameters)}")


UNIT_KEYWORD = _unit_keyword()


def crc16(data):
    """Modbus RTU CRC, low byte first (Serial Line §2.5.1.2)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes([crc & 0xFF, crc >> 8])


def adu(*data):
    """An RTU frame: the bytes given, then their CRC."""
    body = bytes(data)
    return body + crc16(body)


def wait_for(predicate, timeout, what, interval=0.05):
    """Poll `predicate` until it returns something truthy (returned), at most `timeout` s."""
    deadline = time.monotonic() + timeout
    last = None
    while True:
        last = predicate()
        if last:
            return last
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for: {what} (last: {last!r})")
        time.sleep(interval)


class PlcMaster:
    """Checked Modbus calls on a pymodbus client (`self.client`), and the axis helpers a PLC
    program would use. Subclasses provide `raw_exchange(frame, wait)`."""

    def __init__(self, client):
        self.client = client

    # ------------------------------------------------------------------ Modbus, checked

    def _call(self, method, *args, **kwargs):
        kwargs[UNIT_KEYWORD] = kwargs.pop("unit")
        response = getattr(self.client, method)(*args, **kwargs)
        if response.isError():
            code = getattr(response, "exception_code", None)
            if code is None:
                raise ModbusException(f"{method}: {response}")
            raise ModbusError(getattr(response, "function_code", 0) & 0x7F, code)
        return response

    def read(self, unit, address, count=1):
        return list(self._call("read_holding_registers", address, count=count, unit=unit).registers)

    def read_input(self, unit, address, count=1):
        return list(self._call("read_input_registers", address, count=count, unit=unit).registers)

    def write(self, unit, address, values):
        """FC06 for one value, FC10 for a list."""
        if isinstance(values, int):
            self._call("write_register", address, values, unit=unit)
        else:
            self._call("write_registers", address, list(values), unit=unit)

    def acknowledge(self, timeout=5):
        """Acknowledges FAILSAFE once its cause is gone. The gateway refuses (03) while the stop
        input is still active, so a caller that has just closed it waits until the gateway has
        seen it closed."""

        def taken():
            try:
                self.write(GATEWAY_UNIT, G_FAILSAFE, 0)
                return True
            except ModbusError as refused:
                if refused.code != ILLEGAL_DATA_VALUE:
                    raise
                return False

        wait_for(taken, timeout, "FAILSAFE acknowledged (its cause gone)")

    def coil(self, unit, address, on):
        self._call("write_coil", address, bool(on), unit=unit)

    def read_coils(self, unit, address, count=1):
        return list(self._call("read_coils", address, count=count, unit=unit).bits[:count])

    def call(self, method, *args, unit, **kwargs):
        """Any pymodbus client method, with the unit keyword of the installed version."""
        return self._call(method, *args, unit=unit, **kwargs)

    def exception(self, function, *args, **kwargs):
        """The exception code the gateway answers a request with (fails if it succeeds)."""
        try:
            function(*args, **kwargs)
        except ModbusError as error:
            return error.code
        raise AssertionError(f"{function.__name__}{args} succeeded; an exception was expected")

    # ------------------------------------------------------------------ axis helpers

    def pnow(self, axis):
        hi, lo = self.read(unit(axis), PNOW, 2)
        value = (hi << 16) | lo
        return value - (1 << 32) if value & 0x8000_0000 else value

    def dss1(self, axis):
        return self.read(unit(axis), DSS1)[0]

    def cmst(self, axis):
        state, reason = self.read(unit(axis), CMST, 2)
        return state, reason

    def settle(self, axis, timeout=15.0):
        """Poll like a PLC until the axis' last command is done or failed: (CMST, CMER)."""
        return wait_for(
            lambda: (lambda s: s if s[0] in (DONE, FAILED) else None)(self.cmst(axis)),
            timeout,
            f"axis {axis}: command settles",
        )

    def servo_on(self, axis):
        self.write(unit(axis), DRG1, DRG1_SON)
        assert self.settle(axis) == (DONE, 0)

    def home(self, axis):
        """Servo on, home (DRG1 HOME edge), wait HEND, release HOME."""
        self.servo_on(axis)
        self.write(unit(axis), DRG1, DRG1_SON | DRG1_HOME)
        wait_for(lambda: self.dss1(axis) & DSS1_HEND, 20.0, f"axis {axis}: HEND")
        assert self.settle(axis) == (DONE, 0)
        self.write(unit(axis), DRG1, DRG1_SON)

    def direct(self, axis, target, speed=100_00, accel=30, band=10, registers=7, ctlf=0):
        """FC10 at 0x9900: PCMD (0.01 mm), INP, VCMD (0.01 mm/s), ACMD (0.01 G)[, PPOW, CTLF]."""
        p = target & 0xFFFF_FFFF
        values = [p >> 16, p & 0xFFFF, band >> 16, band & 0xFFFF, speed >> 16, speed & 0xFFFF, accel]
        if registers == 9:
            values += [0, ctlf]
        self.write(unit(axis), DIRECT, values)

    def channel(self, request, timeout=10.0):
        """One command-channel exchange: write REQ, wait for RESP, clear REQ, see RESP clear."""
        assert self.read(GATEWAY_UNIT, G_RESPONSE)[0] == 0, "response clear before a request"
        self.write(GATEWAY_UNIT, G_REQUEST, request)
        response = wait_for(
            lambda: (lambda r: r if r[0] != 0 else None)(self.read(GATEWAY_UNIT, G_RESPONSE, 5)),
            timeout,
            f"response to {request}",
        )
        self.write(GATEWAY_UNIT, G_REQUEST, 0)
        assert self.read(GATEWAY_UNIT, G_RESPONSE, 5) == [0] * 5, "response cleared"
        return response
