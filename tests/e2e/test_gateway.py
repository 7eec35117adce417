"""The gateway end to end: pymodbus (a real Modbus RTU master) -> pseudo-terminal ->
rc-gateway-host (the firmware's engine and register map) -> simulated Robo Cylinder controllers.

Behaviour is checked through the registers a PLC reads, and through the simulator's own view
(`stats` on the gateway's control line): what the controllers received, whether they move, where
they are. Axis n is unit n + 1; the gateway is unit 63. Simulated axes: 8 mm lead, 100 mm
stroke, homing at the motor end, point 1 = 20 mm and point 3 = 40 mm.
"""

import time

from conftest import (
    ALMC,
    CMCT,
    COIL_ALRS,
    COIL_STOP,
    COIL_STP,
    DIRECT,
    DONE,
    DOPM,
    DOPM_ALM_N,
    DRG1,
    DRG1_CSTR,
    DRG1_SON,
    DSS1,
    DSS1_ALMH,
    DSS1_PEND,
    DSS1_STP,
    DSS1_SV,
    FAILED,
    G_FAILSAFE,
    G_FAILSAFE_COUNT,
    G_REQUEST,
    G_RESPONSE,
    G_SYNC_MASK,
    G_SYNC_START,
    G_SYNC_STATUS,
    G_VERSION,
    G_WATCHDOG,
    GATEWAY_UNIT,
    ILLEGAL_DATA_ADDRESS,
    ILLEGAL_DATA_VALUE,
    ILLEGAL_FUNCTION,
    PNOW,
    POSR,
    REASON_CANCELLED,
    REASON_PAUSED,
    adu,
    unit,
    wait_for,
)



def motion_snapshot(gw, axes=(0, 1, 2)):
    """What must not change when a request is refused: commands sent to each axis (frames other
    than the status and position polls), whether it moves, where it is, and CMCT."""
    stats = gw.stats()["axes"]
    return [
        (
            stats[a]["commands"],
            stats[a]["moving"],
            stats[a]["position"],
            gw.read(unit(a), CMCT)[0],
        )
        for a in axes
    ]


def test_servo_on_and_off(gateway):
    gw = gateway
    gw.servo_on(0)
    assert gw.dss1(0) & DSS1_SV
    # SON is a level: clearing it turns the servo off.
    gw.write(unit(0), DRG1, 0)
    assert gw.settle(0) == (DONE, 0)
    wait_for(lambda: not gw.dss1(0) & DSS1_SV, 5.0, "SV off")
    assert gw.sim(0)["servo"] is False
    gw.servo_on(0)
    wait_for(lambda: gw.dss1(0) & DSS1_SV, 5.0, "SV on")
    assert gw.sim(0)["servo"] is True
    assert gw.read(unit(0), CMCT)[0] == 3, "three commands taken"


def test_home(gateway):
    gw = gateway
    assert not gw.dss1(0) & (1 << 4), "not homed at power-up"
    gw.home(0)
    sim = gw.sim(0)
    assert sim["homed"] and not sim["homing"]
    assert sim["position"] == 0, "the simulator's PNOW at home is 0 pulses"
    # The gateway negates motor-end positions exactly: home reads 0.00 mm.
    assert gw.pnow(0) == 0
    assert abs(sim["position_mm100"]) <= 1


def test_move_to_point(gateway):
    gw = gateway
    gw.home(0)
    gw.write(unit(0), POSR, 3)
    gw.write(unit(0), DRG1, DRG1_SON | DRG1_CSTR)
    assert gw.settle(0) == (DONE, 0)
    wait_for(lambda: gw.dss1(0) & DSS1_PEND, 5.0, "PEND")
    assert gw.pnow(0) == 40_00, "point 3 is 40.00 mm"
    assert gw.read(unit(0), DOPM)[0] & 0xF == 3, "PM1-PM8 show the completed position"
    assert gw.sim(0)["position_mm100"] == 40_00
    gw.write(unit(0), DRG1, DRG1_SON)


def test_direct_numeric_move(gateway):
    gw = gateway
    gw.home(1)
    # 7 registers: 62.50 mm at 50 mm/s, 0.3 G.
    gw.direct(1, 62_50, speed=50_00)
    assert gw.settle(1) == (DONE, 0)
    wait_for(lambda: gw.pnow(1) == 62_50, 5.0, "PNOW 62.50 mm")
    # 9 registers, incremental (CTLF bit 3): -12.50 mm.
    gw.direct(1, -12_50, speed=50_00, registers=9, ctlf=1 << 3)
    assert gw.settle(1) == (DONE, 0)
    wait_for(lambda: gw.pnow(1) == 50_00, 5.0, "PNOW 50.00 mm")
    assert gw.sim(1)["position_mm100"] == 50_00
    # The same status block through FC04.
    assert gw.read_input(unit(1), PNOW, 2) == [0, 50_00]


def test_jog_and_stop(gateway):
    gw = gateway
    gw.home(0)
    # Toward the far end at 10 mm/s: 9.5 s of travel.
    gw.direct(0, 95_00, speed=10_00)
    wait_for(lambda: gw.sim(0)["moving"] and gw.cmst(0)[0] == 1, 5.0, "moving")
    time.sleep(0.5)
    gw.coil(unit(0), COIL_STOP, True)
    wait_for(lambda: not gw.sim(0)["moving"] and gw.cmst(0)[0] != 1, 5.0, "stopped")
    sim = gw.sim(0)
    assert 0 < sim["position_mm100"] < 50_00, f"stopped short: {sim}"
    # PNOW follows the stopped axis.
    wait_for(lambda: abs(gw.pnow(0) - sim["position_mm100"]) <= 1, 5.0, "PNOW at the stop")
    state, reason = gw.cmst(0)
    # A stop is an interrupt, not a command: CMST shows the move it cancelled.
    assert (state, reason) == (FAILED, REASON_CANCELLED << 8), (state, reason)
    assert gw.read_coils(unit(0), COIL_STOP) == [False], "STOP reads 0"
    assert gw.read(unit(0), CMCT)[0] == 3, "SON, HOME, the move (a stop is not counted)"



def test_pause_with_stp(gateway):
    gw = gateway
    gw.home(0)
    gw.write(unit(0), POSR, 3)
    gw.direct(0, 95_00, speed=10_00)
    wait_for(lambda: gw.sim(0)["moving"], 5.0, "moving")
    gw.coil(unit(0), COIL_STP, True)
    wait_for(lambda: not gw.sim(0)["moving"], 5.0, "paused")
    assert gw.dss1(0) & DSS1_STP, "STP shown in DSS1"
    assert gw.read(unit(0), DRG1)[0] & (1 << 5), "the STP coil is DRG1 bit 5"
    before = gw.sim(0)
    # CSTR while STP is on: refused, and nothing moves.
    gw.write(unit(0), DRG1, DRG1_SON | (1 << 5) | DRG1_CSTR)
    assert gw.cmst(0) == (FAILED, REASON_PAUSED << 8)
    time.sleep(0.3)
    after = gw.sim(0)
    assert not after["moving"] and after["position"] == before["position"]
    assert after["commands"] == before["commands"], "no command reached the axis"
    # Release: the move does not resume, a new start works.
    gw.coil(unit(0), COIL_STP, False)
    assert not gw.dss1(0) & DSS1_STP
    time.sleep(0.2)
    assert not gw.sim(0)["moving"], "no resume"
    gw.write(unit(0), DRG1, DRG1_SON)
    gw.write(unit(0), DRG1, DRG1_SON | DRG1_CSTR)
    assert gw.settle(0) == (DONE, 0)
    wait_for(lambda: gw.pnow(0) == 40_00, 5.0, "at point 3")


def test_alarm_and_reset(gateway):
    gw = gateway
    gw.home(2)
    assert gw.control("alarm 2 D8") == {"ok": True, "cmd": "alarm"}
    wait_for(lambda: gw.dss1(2) & DSS1_ALMH, 5.0, "ALMH")
    assert gw.read(unit(2), ALMC)[0] == 0xD8
    assert not gw.read(unit(2), DOPM)[0] & DOPM_ALM_N, "*ALM off (active low)"
    assert gw.sim(2)["alarm"] == 0xD8
    gw.coil(unit(2), COIL_ALRS, True)
    wait_for(lambda: not gw.dss1(2) & DSS1_ALMH, 5.0, "alarm cleared")
    assert gw.read(unit(2), ALMC)[0] == 0
    assert gw.read(unit(2), DOPM)[0] & DOPM_ALM_N
    assert gw.sim(2)["alarm"] == 0
    gw.coil(unit(2), COIL_ALRS, False)
    # A warning is not an alarm: refused by the simulator.
    assert gw.control("alarm 2 74")["ok"] is False


def test_point_table_write_and_read_back(gateway):
    gw = gateway
    velocity, position = 4, 0  # field offsets from 0x400: VCMD, PCMD
    value = 123_45  # 0.01 mm/s: 4629 x 0.2 rpm with the 8 mm lead (4629.375 truncated)
    held = 123_44  # what the controller holds, in 0.01 mm/s
    stores = gw.sim(0)["nv_writes"]
    first = gw.channel([2, 0, 5, velocity, value >> 16, value & 0xFFFF])
    assert first[:4] == [2, 0, 0, held], first
    assert 1 <= first[4] < 0xFFFF, f"written with V5: {first}"
    assert gw.sim(0)["nv_writes"] == stores + 1
    readback = gw.channel([1, 0, 5, velocity, 0, 0])
    assert readback == [1, 0, 0, held, 0], readback
    assert gw.channel([3, 0, 5, velocity, 0, 0]) == [3, 0, 0, 4629, 0], "code 3: as stored"
    again = gw.channel([2, 0, 5, velocity, value >> 16, value & 0xFFFF])
    assert again == [2, 0, 0, held, 0xFFFF], f"unchanged: no V5 spent: {again}"
    assert gw.sim(0)["nv_writes"] == stores + 1
    # A position past the 100 mm stroke: refused, nothing stored.
    assert (
        gw.exception(gw.write, GATEWAY_UNIT, G_REQUEST, [2, 0, 5, position, 0, 200_00])
        == ILLEGAL_DATA_VALUE
    )
    assert gw.read(GATEWAY_UNIT, G_RESPONSE, 5) == [0] * 5
    assert gw.sim(0)["nv_writes"] == stores + 1
    # Invalid request: point 16.
    assert (
        gw.exception(gw.write, GATEWAY_UNIT, G_REQUEST, [1, 0, 16, velocity, 0, 0])
        == ILLEGAL_DATA_VALUE
    )


def test_synchronized_start(gateway):
    gw = gateway
    gw.home(0)
    gw.home(1)
    gw.write(unit(0), POSR, 3)
    gw.write(unit(1), POSR, 1)
    gw.write(GATEWAY_UNIT, G_SYNC_MASK, 0b011)
    gw.write(GATEWAY_UNIT, G_SYNC_START, 1)
    wait_for(lambda: gw.read(GATEWAY_UNIT, G_SYNC_STATUS)[0] == 2, 10.0, "SYNCSTAT done")
    wait_for(lambda: gw.dss1(0) & DSS1_PEND and gw.dss1(1) & DSS1_PEND, 10.0, "both PEND")
    assert gw.pnow(0) == 40_00
    assert gw.pnow(1) == 20_00
    s = gw.stats()["axes"]
    assert s[0]["last_move_start"] is not None
    assert s[0]["last_move_start"] == s[1]["last_move_start"], "started at the same instant"
    assert s[2]["commands"] == 0, "axis 2 was not in the mask"
    # Axis 3 is not configured.
    assert gw.exception(gw.write, GATEWAY_UNIT, G_SYNC_MASK, 0b1000) == ILLEGAL_DATA_VALUE


def test_watchdog_stops_on_plc_silence(gateway):
    gw = gateway
    gw.home(0)
    gw.write(GATEWAY_UNIT, G_WATCHDOG, 500)
    assert gw.read(GATEWAY_UNIT, G_WATCHDOG) == [500]
    assert gw.read(GATEWAY_UNIT, G_FAILSAFE, 2) == [0, 0]
    gw.direct(0, 95_00, speed=10_00)
    wait_for(lambda: gw.sim(0)["moving"], 2.0, "moving", interval=0.02)
    # The PLC goes silent (the control line is not Modbus: it does not feed the watchdog).
    time.sleep(1.5)
    sim = gw.sim(0)
    assert not sim["moving"], f"stopped by the watchdog: {sim}"
    assert 0 < sim["position_mm100"] < 30_00, f"stopped short: {sim}"
    assert sim["sent"].get("d", 0) >= 1, f"a stop (d) was sent: {sim}"
    assert gw.stats()["failsafe"] & 1
    assert gw.read(GATEWAY_UNIT, G_FAILSAFE, 2) == [1, 1], "latched, counted"
    # The fail-safe's stop is not a PLC command: CMST still shows the move, cancelled.
    assert gw.cmst(0) == (FAILED, REASON_CANCELLED << 8)
    gw.write(GATEWAY_UNIT, G_FAILSAFE, 0)
    assert gw.read(GATEWAY_UNIT, G_FAILSAFE)[0] == 0
    assert gw.read(GATEWAY_UNIT, G_FAILSAFE_COUNT)[0] == 1


def test_invalid_requests_get_exceptions_and_never_reach_the_bus(gateway):
    gw = gateway
    gw.home(0)
    time.sleep(0.2)
    before = motion_snapshot(gw)
    u = unit(0)
    cases = [
        # Unknown addresses: 02.
        ("read 0x1234", lambda: gw.read(u, 0x1234), ILLEGAL_DATA_ADDRESS),
        ("write 0x1234", lambda: gw.write(u, 0x1234, 1), ILLEGAL_DATA_ADDRESS),
        ("coil 0x0404", lambda: gw.coil(u, 0x0404, True), ILLEGAL_DATA_ADDRESS),
        ("FC04 DRG1", lambda: gw.read_input(u, DRG1), ILLEGAL_DATA_ADDRESS),
        ("gateway 0x0050", lambda: gw.read(GATEWAY_UNIT, 0x0050), ILLEGAL_DATA_ADDRESS),
        ("direct 4 regs", lambda: gw.write(u, DIRECT, [0, 10_00, 0, 10]), ILLEGAL_DATA_ADDRESS),
        # Bad values: 03.
        ("POSR 16", lambda: gw.write(u, POSR, 16), ILLEGAL_DATA_VALUE),
        ("DRG1 BKRL", lambda: gw.write(u, DRG1, DRG1_SON | 1 << 7), ILLEGAL_DATA_VALUE),
        ("beyond stroke", lambda: gw.direct(0, 100_01), ILLEGAL_DATA_VALUE),
        ("negative", lambda: gw.direct(0, -1), ILLEGAL_DATA_VALUE),
        ("zero speed", lambda: gw.direct(0, 10_00, speed=0), ILLEGAL_DATA_VALUE),
        ("write PNOW", lambda: gw.write(u, PNOW, 1), ILLEGAL_DATA_VALUE),
        ("watchdog 10", lambda: gw.write(GATEWAY_UNIT, G_WATCHDOG, 10), ILLEGAL_DATA_VALUE),
        ("FAILSAFE 1", lambda: gw.write(GATEWAY_UNIT, G_FAILSAFE, 1), ILLEGAL_DATA_VALUE),
        # Function codes the gateway does not implement: 01.
        (
            "FC16 mask write",
            lambda: gw.call("mask_write_register", address=DRG1, and_mask=0, or_mask=DRG1_SON, unit=u),
            ILLEGAL_FUNCTION,
        ),
        (
            "FC17 read/write",
            lambda: gw.call(
                "readwrite_registers",
                read_address=DSS1,
                read_count=1,
                write_address=DRG1,
                values=[DRG1_SON | DRG1_CSTR],
                unit=u,
            ),
            ILLEGAL_FUNCTION,
        ),
    ]
    for name, request, expected in cases:
        assert gw.exception(request) == expected, name
    # FC2B is served for MEI type 0x0E only; a malformed request gets the spec's exception
    # (Application Protocol §6.21): another MEI type 01, an unknown ReadDevId code 03.
    for name, request, expected in [
        ("FC2B MEI 0x0D", adu(u, 0x2B, 0x0D, 0x01, 0x00), ILLEGAL_FUNCTION),
        ("FC2B code 5", adu(u, 0x2B, 0x0E, 0x05, 0x00), ILLEGAL_DATA_VALUE),
    ]:
        reply = gw.raw_exchange(request)
        assert reply[:3] == bytes([u, 0xAB, expected]), (name, reply.hex(" "))
    # A unit the gateway does not serve gets no reply at all.
    assert gw.raw_exchange(adu(unit(5), 0x03, 0x90, 0x05, 0x00, 0x01)) == b""
    time.sleep(0.3)
    after = motion_snapshot(gw)
    assert after == before, f"nothing reached the bus: {before} -> {after}"
    assert gw.read(u, DRG1) == [DRG1_SON], "state untouched"
    assert gw.read(u, POSR) == [0]
    counters = gw.stats()["modbus"]["exceptions"]
    assert counters[0] >= 3 and counters[1] >= 6 and counters[2] >= 8, counters


def test_garbage_and_crc_errors_get_no_reply(gateway):
    gw = gateway
    stats = gw.stats()["modbus"]
    good = adu(unit(0), 0x03, 0x90, 0x05, 0x00, 0x01)
    # The raw path works: a good frame gets its reply (unit, FC, 2 bytes, DSS1, CRC).
    reply = gw.raw_exchange(good)
    assert len(reply) == 7 and reply[:3] == bytes([1, 3, 2]), reply.hex(" ")
    bad_crc = bytearray(good)
    bad_crc[-1] ^= 0xFF
    assert gw.raw_exchange(bad_crc) == b"", "bad CRC: no reply"
    assert gw.raw_exchange(b"\x55\xaa") == b"", "too short: no reply"
    assert gw.raw_exchange(bytes(range(0x20, 0x60))) == b"", "garbage: no reply"
    # A frame whose function code is not a request (>= 0x80): no reply.
    assert gw.raw_exchange(adu(unit(0), 0x83, 0x02)) == b""
    after = gw.stats()["modbus"]
    assert after["crc_errors"] >= stats["crc_errors"] + 2, after
    assert after["too_short"] >= stats["too_short"] + 1, after
    assert after["malformed"] >= stats["malformed"] + 1, after
    # The next request through pymodbus works.
    assert gw.read(GATEWAY_UNIT, G_VERSION, 2)[0] == 0x0001
    assert gw.dss1(0) & DSS1_SV
    # FC08 sub-function 0 (return query data) echoes.
    echo = gw.call("diag_query_data", msg=b"\x12\x34", unit=unit(0))
    assert not echo.isError()
