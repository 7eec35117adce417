/*
 * Interop: libmodbus (a Modbus RTU master nobody in this project wrote) against rc-gateway-host
 * through its pseudo-terminal. scripts/interop.sh builds and runs it.
 *
 *   libmodbus_client [-v] DEVICE VERSION AXES GROUP...
 *
 * DEVICE   the PLC line rc-gateway-host printed (`PLC /dev/pts/N`), or `tcp:HOST:PORT` for
 *          Modbus TCP (modbus_new_tcp)
 * VERSION  the firmware version the gateway reports ("0.1.0"), as protocol/Cargo.toml says
 * AXES     how many simulated axes it runs (axis n is unit n + 1; the gateway is unit 63)
 * GROUP    `valid`: requests the gateway carries out; `invalid`: requests it must refuse (with
 *          the documented exception, or no reply at all), after which nothing of the axes'
 *          state may have changed (the script also checks that nothing reached the bus);
 *          `tcp`: what differs on Modbus TCP (unit 0xFF, exception 0A, a function not served)
 *          and the gateway unit's requests; `tcp-axes`: the axes over TCP (simulated ones)
 * -v       libmodbus debug output (every frame) on standard error
 *
 * One line per scenario: `ok <name>` or `FAIL <name>: <why>`; exit status 1 if any failed.
 * Values are checked against README.md's register map and "Modbus functions" section, not
 * only "no error". Every wait is bounded (tens of seconds at most); nothing is timed.
 */

#include <errno.h>
#include <poll.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <modbus.h>

/* Units. */
#define GATEWAY 63
#define NOT_SERVED 20

/* Axis registers (README: register map; protocol/src/plc/map.rs). */
#define PNOW 0x9000
#define ALMC 0x9002
#define DOPM 0x9004
#define DSS1 0x9005
#define DSS2 0x9006
#define CMST 0x9F00
#define LINK 0x9F02
#define CMCT 0x9F03
#define DRG1 0x0D00
#define POSR 0x0D03
#define DIRECT 0x9900
#define COIL_SON 0x0403
#define COIL_STP 0x040A
#define COIL_HOME 0x040B
#define COIL_STOP 0x042C
#define DRG1_SON (1u << 12)
#define DSS1_PWR (1u << 13)
#define DSS1_SV (1u << 12)
#define DSS1_STP (1u << 5)
#define DSS1_HEND (1u << 4)
#define DSS1_PEND (1u << 3)
#define DOPM_ALM_N (1u << 14)
#define DOPM_SV (1u << 12)
#define CMST_DONE 2
/* Gateway unit. */
#define G_VERSION 0x0000
#define G_FAILSAFE 0x0004
#define G_WATCHDOG 0x0006
#define G_BUSBAUD 0x0007
#define G_BUSRTIM 0x0008
#define G_AXISCFG 0x0100
#define G_PLCLINK 0x0510

/* Modbus exception codes. */
#define X_FUNCTION 1
#define X_ADDRESS 2
#define X_VALUE 3

#define TIMEOUT_S 20.0

static modbus_t *ctx;
static int failures;
static int scenarios;
static int axes;
static unsigned version_major, version_minor, version_patch;
static char version_text[32];
static char why[512];

/* ------------------------------------------------------------------------------ reporting */

/* Records why the current scenario failed (the first reason wins) and returns -1. */
static int fail(const char *format, ...)
{
    if (why[0] == '\0') {
        va_list args;
        va_start(args, format);
        vsnprintf(why, sizeof why, format, args);
        va_end(args);
    }
    return -1;
}

#define CHECK(condition, ...)                                                                  \
    do {                                                                                       \
        if (!(condition))                                                                      \
            return fail(__VA_ARGS__);                                                          \
    } while (0)

static void run(const char *name, int (*scenario)(void))
{
    why[0] = '\0';
    scenarios++;
    if (scenario() == 0 && why[0] == '\0') {
        printf("ok %s\n", name);
    } else {
        failures++;
        printf("FAIL %s: %s\n", name, why[0] ? why : "failed");
    }
    fflush(stdout);
}

/* ------------------------------------------------------------------------------ helpers */

static double now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + t.tv_nsec / 1e9;
}

static void sleep_ms(int ms)
{
    struct timespec t = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&t, NULL);
}

/* FC03 of `count` registers at `unit`, checked. */
static int read_regs(int unit, int address, int count, uint16_t *out)
{
    modbus_set_slave(ctx, unit);
    int n = modbus_read_registers(ctx, address, count, out);
    CHECK(n == count, "FC03 unit %d 0x%04X x%d: %s", unit, address, count,
          n < 0 ? modbus_strerror(errno) : "short reply");
    return 0;
}

static int read_reg(int unit, int address, uint16_t *out)
{
    return read_regs(unit, address, 1, out);
}

static int write_reg(int unit, int address, uint16_t value)
{
    modbus_set_slave(ctx, unit);
    CHECK(modbus_write_register(ctx, address, value) == 1, "FC06 unit %d 0x%04X = 0x%04X: %s",
          unit, address, value, modbus_strerror(errno));
    return 0;
}

/* Polls register `address` until (value & mask) == want, at most TIMEOUT_S. */
static int wait_reg(int unit, int address, uint16_t mask, uint16_t want, const char *what)
{
    double deadline = now() + TIMEOUT_S;
    uint16_t value = 0;
    for (;;) {
        if (read_reg(unit, address, &value) == 0 && (value & mask) == want)
            return 0;
        why[0] = '\0';
        if (now() > deadline)
            return fail("timed out after %.0f s waiting for %s (0x%04X = 0x%04X)", TIMEOUT_S,
                        what, address, value);
        sleep_ms(50);
    }
}

/* Waits until the axis' last command is done (CMST 2, CMER 0). */
static int settle(int unit)
{
    uint16_t st[2] = {0, 0};
    double deadline = now() + TIMEOUT_S;
    for (;;) {
        if (read_regs(unit, CMST, 2, st) < 0)
            return -1;
        if (st[0] == CMST_DONE || st[0] == 3)
            break;
        if (now() > deadline)
            return fail("unit %d: command did not settle (CMST %u)", unit, st[0]);
        sleep_ms(50);
    }
    CHECK(st[0] == CMST_DONE && st[1] == 0, "unit %d: CMST %u CMER 0x%04X, want 2 (done), 0",
          unit, st[0], st[1]);
    return 0;
}

static int32_t pnow(int unit, int *error)
{
    uint16_t r[2];
    *error = read_regs(unit, PNOW, 2, r);
    return (int32_t)(((uint32_t)r[0] << 16) | r[1]);
}

static uint16_t crc16(const uint8_t *data, int length)
{
    uint16_t crc = 0xFFFF;
    for (int i = 0; i < length; i++) {
        crc ^= data[i];
        for (int bit = 0; bit < 8; bit++)
            crc = (crc & 1) ? (crc >> 1) ^ 0xA001 : crc >> 1;
    }
    return crc;
}

/* The length of the RTU reply that starts with `rsp[0..have]`, or 0 while it cannot tell yet.
 * libmodbus 3.1's modbus_receive_confirmation() only knows the lengths of the functions it has
 * calls for: an FC08 or FC2B reply would be cut after its third byte (and fail its CRC check),
 * so replies to raw requests are read here. */
static int reply_length(const uint8_t *rsp, int have)
{
    if (have < 2)
        return 0;
    uint8_t function = rsp[1];
    if (function & 0x80)
        return 5;
    switch (function) {
    case 0x08:
        return 8;
    case 0x01:
    case 0x02:
    case 0x03:
    case 0x04:
    case 0x11:
        return have < 3 ? 0 : 3 + rsp[2] + 2;
    case 0x2B: {
        /* unit, 2B, MEI, code, conformity, more, next, count, then (id, length, value)... */
        if (have < 8)
            return 0;
        int at = 8;
        for (int object = 0; object < rsp[7]; object++) {
            if (have < at + 2)
                return 0;
            at += 2 + rsp[at + 1];
        }
        return at + 2;
    }
    default:
        return 8; /* 05, 06, 0F, 10 */
    }
}

/* Sends `req` (unit, function, data; libmodbus appends the CRC) and reads the reply: its length
 * with a good CRC, 0 if nothing came within `wait_s`, or -1 (why set). */
static int raw(const uint8_t *req, int length, uint8_t *rsp, int size, double wait_s)
{
    int fd = modbus_get_socket(ctx);
    modbus_flush(ctx);
    modbus_set_slave(ctx, req[0]);
    CHECK(modbus_send_raw_request(ctx, (uint8_t *)req, length) == length + 2,
          "modbus_send_raw_request: %s", modbus_strerror(errno));
    int have = 0, want = 0;
    double deadline = now() + wait_s;
    while (want == 0 || have < want) {
        int left = (int)((deadline - now()) * 1000);
        if (left <= 0)
            break;
        struct pollfd p = {fd, POLLIN, 0};
        if (poll(&p, 1, left) <= 0)
            continue;
        ssize_t n = read(fd, rsp + have, size - have);
        CHECK(n > 0, "read: %s", n < 0 ? strerror(errno) : "end of file");
        have += n;
        want = reply_length(rsp, have);
        CHECK(want <= size, "reply too long");
    }
    if (have == 0)
        return 0;
    CHECK(want != 0 && have == want, "reply of %d bytes, expected %d", have, want);
    uint16_t crc = crc16(rsp, have - 2);
    CHECK(rsp[have - 2] == (crc & 0xFF) && rsp[have - 1] == (crc >> 8), "reply with a bad CRC");
    CHECK(rsp[0] == req[0], "reply from unit %d to unit %d", rsp[0], req[0]);
    return have;
}

/* Writes `frame` exactly as given (no CRC added: it may be broken on purpose) and returns how
 * many bytes came back within `wait_s`. */
static int raw_bytes(const uint8_t *frame, int length, double wait_s)
{
    int fd = modbus_get_socket(ctx);
    modbus_flush(ctx);
    CHECK(write(fd, frame, length) == length, "write: %s", strerror(errno));
    uint8_t junk[260];
    int have = 0;
    double deadline = now() + wait_s;
    for (;;) {
        int left = (int)((deadline - now()) * 1000);
        if (left <= 0)
            return have;
        struct pollfd p = {fd, POLLIN, 0};
        if (poll(&p, 1, left) > 0) {
            ssize_t n = read(fd, junk, sizeof junk);
            if (n > 0)
                have += n;
        }
    }
}

/* FC08 sub-function `sub` with data 0000 at `unit`: the value it returns. */
static int diag(int unit, uint16_t sub, uint16_t *value)
{
    uint8_t req[] = {unit, 0x08, sub >> 8, sub & 0xFF, 0x00, 0x00};
    uint8_t rsp[16];
    int n = raw(req, sizeof req, rsp, sizeof rsp, 2.0);
    if (n < 0)
        return -1;
    CHECK(n > 0, "FC08/%02X: no reply", sub);
    CHECK(rsp[1] == 0x08, "FC08/%02X: exception %u", sub, rsp[2]);
    CHECK(rsp[2] == req[2] && rsp[3] == req[3], "FC08/%02X: sub-function %02X%02X echoed", sub,
          rsp[2], rsp[3]);
    *value = (uint16_t)(rsp[4] << 8 | rsp[5]);
    return 0;
}

/* `request` (a libmodbus call returning -1 on error) must fail with exception `code`. */
#define EXPECT_EXCEPTION(code, call, what)                                                     \
    do {                                                                                       \
        errno = 0;                                                                             \
        int rc_ = (call);                                                                      \
        CHECK(rc_ == -1, "%s succeeded; exception %02d expected", what, code);                 \
        CHECK(errno == (int)(MODBUS_ENOBASE + (code)), "%s: %s, expected exception %02d",     \
              what, modbus_strerror(errno), code);                                             \
    } while (0)

/* A raw request that must get exception `code` (reply unit, function | 0x80, code). */
static int raw_exception(const uint8_t *req, int length, int code, const char *what)
{
    uint8_t rsp[260];
    int n = raw(req, length, rsp, sizeof rsp, 2.0);
    if (n < 0)
        return fail("%s: %s", what, why);
    CHECK(n > 0, "%s: no reply, expected exception %02d", what, code);
    CHECK(rsp[1] == (req[1] | 0x80) && rsp[2] == code, "%s: reply %02X %02X, expected %02X %02X",
          what, rsp[1], rsp[2], req[1] | 0x80, code);
    return 0;
}

/* ------------------------------------------------------------------------------ valid */

static int axes_online(void)
{
    for (int unit = 1; unit <= axes; unit++)
        if (wait_reg(unit, LINK, 0xFFFF, 1, "LINK = 1 (online)") < 0)
            return -1;
    return 0;
}

static int fc03_gateway_version(void)
{
    uint16_t r[2];
    if (read_regs(GATEWAY, G_VERSION, 2, r) < 0)
        return -1;
    uint16_t major_minor = (uint16_t)(version_major << 8 | version_minor);
    CHECK(r[0] == major_minor && r[1] == version_patch,
          "VERSION = 0x%04X 0x%04X, expected 0x%04X 0x%04X (%s)", r[0], r[1], major_minor,
          version_patch, version_text);
    return 0;
}

static int fc03_gateway_settings(void)
{
    /* FAILSAFE, FSCOUNT, WATCHDOG, BUSBAUD, BUSRTIM as rc-gateway-host was started:
     * no trip, watchdog off (--watchdog-ms 0), 115200 bit/s, RTIM 3 ms. */
    uint16_t r[5];
    if (read_regs(GATEWAY, G_FAILSAFE, 5, r) < 0)
        return -1;
    CHECK(r[0] == 0 && r[1] == 0, "FAILSAFE %u FSCOUNT %u, expected 0 0", r[0], r[1]);
    CHECK(r[2] == 0, "WATCHDOG %u, expected 0 (--watchdog-ms 0)", r[2]);
    CHECK(r[3] == 1152, "BUSBAUD %u, expected 1152 (115200 bit/s)", r[3]);
    CHECK(r[4] == 3, "BUSRTIM %u, expected 3 ms", r[4]);
    /* AXISCFG of axis 0: enabled, lead 8.00 mm, home at the motor end (7), ..., stroke
     * 100.00 mm (two registers). */
    uint16_t c[8];
    if (read_regs(GATEWAY, G_AXISCFG, 8, c) < 0)
        return -1;
    CHECK(c[0] == 1 && c[1] == 800 && c[2] == 7, "AXISCFG[0] = %u %u %u, expected 1 800 7", c[0],
          c[1], c[2]);
    CHECK(c[4] == 0 && c[5] == 10000, "AXISCFG[0] stroke %u:%u, expected 0:10000", c[4], c[5]);
    return 0;
}

static int fc06_fc03_gateway_watchdog(void)
{
    uint16_t value;
    if (write_reg(GATEWAY, G_WATCHDOG, 60000) < 0 || read_reg(GATEWAY, G_WATCHDOG, &value) < 0)
        return -1;
    CHECK(value == 60000, "WATCHDOG reads %u after writing 60000", value);
    if (write_reg(GATEWAY, G_WATCHDOG, 0) < 0 || read_reg(GATEWAY, G_WATCHDOG, &value) < 0)
        return -1;
    CHECK(value == 0, "WATCHDOG reads %u after writing 0", value);
    return 0;
}

static int fc03_axis_status(void)
{
    for (int unit = 1; unit <= axes; unit++) {
        uint16_t r[8], g[4];
        if (read_regs(unit, PNOW, 8, r) < 0 || read_regs(unit, CMST, 4, g) < 0)
            return -1;
        CHECK(r[2] == 0, "unit %d ALMC 0x%04X, expected 0 (no alarm)", unit, r[2]);
        CHECK(r[4] & DOPM_ALM_N, "unit %d DOPM 0x%04X: *ALM (b14) off, expected on", unit, r[4]);
        CHECK(r[5] & DSS1_PWR, "unit %d DSS1 0x%04X: PWR (b13) off", unit, r[5]);
        CHECK(!(r[5] & DSS1_HEND), "unit %d DSS1 0x%04X: HEND before homing", unit, r[5]);
        CHECK(r[6] == 0, "unit %d DSS2 0x%04X, expected 0 (always)", unit, r[6]);
        CHECK(g[2] == 1, "unit %d LINK %u, expected 1", unit, g[2]);
        CHECK(g[0] <= 3, "unit %d CMST %u outside 0-3", unit, g[0]);
    }
    return 0;
}

static int fc04_axis_status(void)
{
    uint16_t in[4], hold[4];
    modbus_set_slave(ctx, 1);
    int n = modbus_read_input_registers(ctx, CMST, 4, in);
    CHECK(n == 4, "FC04 0x9F00 x4: %s", modbus_strerror(errno));
    if (read_regs(1, CMST, 4, hold) < 0)
        return -1;
    CHECK(in[2] == 1, "FC04 LINK %u, expected 1", in[2]);
    CHECK(in[3] == hold[3], "FC04 CMCT %u, FC03 CMCT %u: the same register", in[3], hold[3]);
    return 0;
}

static int fc06_servo_off_on(void)
{
    uint16_t count0, count1, value, r[2];
    /* SON is a level: the first write of SON is a command even if the servo is on already
     * (the simulated axes start with it on); clearing it turns the servo off. */
    if (read_reg(1, CMCT, &count0) < 0)
        return -1;
    if (write_reg(1, DRG1, DRG1_SON) < 0 || settle(1) < 0)
        return -1;
    if (write_reg(1, DRG1, 0) < 0 || settle(1) < 0)
        return -1;
    if (wait_reg(1, DSS1, DSS1_SV, 0, "DSS1 SV off") < 0)
        return -1;
    if (write_reg(1, DRG1, DRG1_SON) < 0 || read_reg(1, DRG1, &value) < 0)
        return -1;
    CHECK(value == DRG1_SON, "DRG1 reads 0x%04X after writing 0x1000", value);
    if (settle(1) < 0 || wait_reg(1, DSS1, DSS1_SV, DSS1_SV, "DSS1 SV on") < 0)
        return -1;
    if (read_regs(1, DOPM, 2, r) < 0 || read_reg(1, CMCT, &count1) < 0)
        return -1;
    CHECK(r[0] & DOPM_SV, "DOPM 0x%04X: SV (b12) off with the servo on", r[0]);
    CHECK((uint16_t)(count1 - count0) == 3, "CMCT %u -> %u: three commands taken", count0,
          count1);
    return 0;
}

static int fc01_coil_son(void)
{
    uint8_t bit = 0xAA;
    modbus_set_slave(ctx, 1);
    CHECK(modbus_read_bits(ctx, COIL_SON, 1, &bit) == 1, "FC01 0x0403: %s",
          modbus_strerror(errno));
    CHECK(bit == 1, "SON coil reads %u with DRG1 SON set", bit);
    uint8_t stop = 0xAA;
    CHECK(modbus_read_bits(ctx, COIL_STOP, 1, &stop) == 1, "FC01 0x042C: %s",
          modbus_strerror(errno));
    CHECK(stop == 0, "STOP coil reads %u, documented to read 0", stop);
    return 0;
}

static int fc05_coil_home(void)
{
    /* HOME on its rising edge: the axis homes (HEND), PNOW reads 0.00 mm. */
    modbus_set_slave(ctx, 1);
    CHECK(modbus_write_bit(ctx, COIL_HOME, 0) == 1, "FC05 HOME off: %s", modbus_strerror(errno));
    CHECK(modbus_write_bit(ctx, COIL_HOME, 1) == 1, "FC05 HOME on: %s", modbus_strerror(errno));
    if (wait_reg(1, DSS1, DSS1_HEND, DSS1_HEND, "DSS1 HEND") < 0 || settle(1) < 0)
        return -1;
    modbus_set_slave(ctx, 1);
    CHECK(modbus_write_bit(ctx, COIL_HOME, 0) == 1, "FC05 HOME off: %s", modbus_strerror(errno));
    int error;
    int32_t position = pnow(1, &error);
    if (error)
        return -1;
    CHECK(position == 0, "PNOW %d after homing, expected 0", position);
    return 0;
}

static int fc05_fc0f_coil_stp(void)
{
    /* STP is a level: on shows DSS1 STP, off clears it. FC05 sets it, FC0F clears it. */
    uint8_t bit = 0;
    modbus_set_slave(ctx, 1);
    CHECK(modbus_write_bit(ctx, COIL_STP, 1) == 1, "FC05 STP on: %s", modbus_strerror(errno));
    CHECK(modbus_read_bits(ctx, COIL_STP, 1, &bit) == 1 && bit == 1, "STP coil reads %u", bit);
    if (wait_reg(1, DSS1, DSS1_STP, DSS1_STP, "DSS1 STP on") < 0)
        return -1;
    uint8_t off[1] = {0};
    modbus_set_slave(ctx, 1);
    CHECK(modbus_write_bits(ctx, COIL_STP, 1, off) == 1, "FC0F STP off: %s",
          modbus_strerror(errno));
    CHECK(modbus_read_bits(ctx, COIL_STP, 1, &bit) == 1 && bit == 0, "STP coil reads %u", bit);
    return wait_reg(1, DSS1, DSS1_STP, 0, "DSS1 STP off");
}

static int fc10_direct_move(void)
{
    /* FC10 of 7 registers at 0x9900: 25.00 mm, band 0.10 mm, 100.00 mm/s, 0.30 G. */
    const int32_t target = 2500;
    uint16_t values[7] = {0, target, 0, 10, 0, 10000, 30};
    modbus_set_slave(ctx, 1);
    CHECK(modbus_write_registers(ctx, DIRECT, 7, values) == 7, "FC10 0x9900 x7: %s",
          modbus_strerror(errno));
    if (settle(1) < 0 || wait_reg(1, DSS1, DSS1_PEND, DSS1_PEND, "DSS1 PEND") < 0)
        return -1;
    int error;
    int32_t position = pnow(1, &error);
    if (error)
        return -1;
    CHECK(position == target, "PNOW %d after the move, expected %d", position, target);
    return 0;
}

static int fc10_posr(void)
{
    /* FC10 of one register: POSR = 3, read back; then FC06 back to 0. */
    uint16_t three = 3, value;
    modbus_set_slave(ctx, 2);
    CHECK(modbus_write_registers(ctx, POSR, 1, &three) == 1, "FC10 POSR: %s",
          modbus_strerror(errno));
    if (read_reg(2, POSR, &value) < 0)
        return -1;
    CHECK(value == 3, "POSR reads %u after writing 3", value);
    if (write_reg(2, POSR, 0) < 0 || read_reg(2, POSR, &value) < 0)
        return -1;
    CHECK(value == 0, "POSR reads %u after writing 0", value);
    return 0;
}

static int fc08_echo(void)
{
    for (int unit = 1; unit <= GATEWAY; unit += GATEWAY - 1) {
        uint8_t req[] = {unit, 0x08, 0x00, 0x00, 0x12, 0x34};
        uint8_t rsp[16];
        int n = raw(req, sizeof req, rsp, sizeof rsp, 2.0);
        if (n < 0)
            return -1;
        CHECK(n == 8 && memcmp(rsp, req, sizeof req) == 0,
              "unit %d: %d bytes, not the request echoed", unit, n);
    }
    return 0;
}

static int fc08_counters(void)
{
    /* 0B bus messages and 0E server messages: each of the 3 requests since the first read is
     * one more (the line has no other master); 0C CRC errors unchanged; 10/11 always 0;
     * 02 diagnostic register 0 (no trip, every axis online, no alarm). */
    uint16_t bus0, bus1, server0, server1, errors0, errors1, nak, busy, reg;
    if (diag(GATEWAY, 0x0B, &bus0) < 0 || diag(GATEWAY, 0x0E, &server0) < 0 ||
        diag(GATEWAY, 0x0C, &errors0) < 0)
        return -1;
    uint16_t dummy;
    if (read_reg(1, DSS1, &dummy) < 0)
        return -1;
    if (diag(1, 0x0B, &bus1) < 0 || diag(1, 0x0E, &server1) < 0 || diag(1, 0x0C, &errors1) < 0)
        return -1;
    CHECK((uint16_t)(bus1 - bus0) == 4,
          "bus message count %u -> %u, expected +4", bus0, bus1);
    CHECK((uint16_t)(server1 - server0) == 4, "server message count %u -> %u, expected +4",
          server0, server1);
    CHECK(errors1 == errors0, "CRC error count %u -> %u", errors0, errors1);
    if (diag(GATEWAY, 0x10, &nak) < 0 || diag(GATEWAY, 0x11, &busy) < 0 ||
        diag(GATEWAY, 0x02, &reg) < 0)
        return -1;
    CHECK(nak == 0 && busy == 0, "NAK %u busy %u, documented always 0", nak, busy);
    CHECK(reg == 0, "diagnostic register 0x%04X, expected 0", reg);
    return 0;
}

/* Finds object `id` in an FC2B/0E reply: its value (not NUL-terminated) and length. */
static const uint8_t *object_of(const uint8_t *rsp, int id, int *length)
{
    int at = 8;
    for (int object = 0; object < rsp[7]; object++) {
        if (rsp[at] == id) {
            *length = rsp[at + 1];
            return rsp + at + 2;
        }
        at += 2 + rsp[at + 1];
    }
    return NULL;
}

static int fc2b_device_id(void)
{
    uint8_t rsp[260];
    /* ReadDevId 01 (basic), from object 00: VendorName, ProductCode, MajorMinorRevision. */
    uint8_t basic[] = {GATEWAY, 0x2B, 0x0E, 0x01, 0x00};
    int n = raw(basic, sizeof basic, rsp, sizeof rsp, 2.0);
    if (n < 0)
        return -1;
    CHECK(n > 0, "no reply");
    CHECK(rsp[1] == 0x2B, "exception %u", rsp[2]);
    CHECK(rsp[2] == 0x0E && rsp[3] == 0x01, "MEI %02X code %02X", rsp[2], rsp[3]);
    CHECK(rsp[4] == 0x82, "conformity 0x%02X, documented 0x82", rsp[4]);
    CHECK(rsp[5] == 0 && rsp[7] == 3, "more follows %u, %u objects: expected 0, 3", rsp[5],
          rsp[7]);
    int length;
    const uint8_t *vendor = object_of(rsp, 0x00, &length);
    CHECK(vendor && length > 0, "VendorName (00) missing or empty");
    const uint8_t *code = object_of(rsp, 0x01, &length);
    CHECK(code && length == 5 && memcmp(code, "RC-GW", 5) == 0, "ProductCode (01) %.*s",
          code ? length : 0, code ? (const char *)code : "");
    const uint8_t *revision = object_of(rsp, 0x02, &length);
    CHECK(revision && length == (int)strlen(version_text) &&
              memcmp(revision, version_text, length) == 0,
          "MajorMinorRevision (02) %.*s, expected %s", revision ? length : 0,
          revision ? (const char *)revision : "", version_text);
    /* ReadDevId 02 (regular): objects 00-05. */
    uint8_t regular[] = {1, 0x2B, 0x0E, 0x02, 0x00};
    n = raw(regular, sizeof regular, rsp, sizeof rsp, 2.0);
    if (n < 0)
        return -1;
    CHECK(n > 0 && rsp[1] == 0x2B && rsp[7] == 6, "regular stream: %d bytes, %u objects", n,
          n > 7 ? rsp[7] : 0);
    for (int id = 0; id <= 5; id++)
        CHECK(object_of(rsp, id, &length) != NULL, "regular stream: object %02X missing", id);
    /* ReadDevId 04: object 04 (ProductName) alone. */
    uint8_t one[] = {GATEWAY, 0x2B, 0x0E, 0x04, 0x04};
    n = raw(one, sizeof one, rsp, sizeof rsp, 2.0);
    if (n < 0)
        return -1;
    CHECK(n > 0 && rsp[1] == 0x2B && rsp[3] == 0x04 && rsp[7] == 1 && rsp[8] == 0x04 &&
              rsp[9] > 0,
          "individual object 04: %d bytes", n);
    return 0;
}

static int fc11_report_server_id(void)
{
    char expected[64];
    snprintf(expected, sizeof expected, "RC-GW %s", version_text);
    int units[2] = {GATEWAY, 1};
    for (int i = 0; i < 2; i++) {
        uint8_t id[MODBUS_MAX_PDU_LENGTH];
        modbus_set_slave(ctx, units[i]);
        int n = modbus_report_slave_id(ctx, sizeof id, id);
        CHECK(n >= 2, "unit %d: %s", units[i], modbus_strerror(errno));
        CHECK(id[0] == units[i], "unit %d: server id %u, expected the unit", units[i], id[0]);
        CHECK(id[1] == 0xFF, "unit %d: run indicator 0x%02X, expected 0xFF (ON)", units[i],
              id[1]);
        CHECK(n - 2 == (int)strlen(expected) && memcmp(id + 2, expected, n - 2) == 0,
              "unit %d: \"%.*s\", expected \"%s\"", units[i], n - 2, (const char *)id + 2,
              expected);
    }
    return 0;
}

/* ------------------------------------------------------------------------------ tcp */

#define DIRECT_UNIT 0xFF
#define G_TCPMAX 0x0605

/* On TCP, unit 0xFF is the device at the IP address (TCP Guide 4.4.2): the gateway unit. */
static int tcp_direct_unit(void)
{
    uint16_t a[2], b[2];
    if (read_regs(GATEWAY, G_VERSION, 2, a) < 0 || read_regs(DIRECT_UNIT, G_VERSION, 2, b) < 0)
        return -1;
    CHECK(a[0] == b[0] && a[1] == b[1], "unit 0xFF VERSION %u %u, unit 63 %u %u", b[0], b[1], a[0],
          a[1]);
    uint16_t t[2];
    if (read_regs(DIRECT_UNIT, G_TCPMAX, 2, t) < 0)
        return -1;
    CHECK(t[0] == 4 && t[1] == 60, "TCPMAX TCPIDLE = %u %u, expected 4 60 (the defaults)", t[0],
          t[1]);
    return 0;
}

/* A unit nobody serves: exception 0A (gateway path unavailable), not a time-out. */
static int tcp_unserved_unit(void)
{
    uint16_t r;
    modbus_set_slave(ctx, 99);
    int n = modbus_read_registers(ctx, G_VERSION, 1, &r);
    CHECK(n < 0 && errno == EMBXGPATH, "unit 99: %s, expected gateway path unavailable",
          n < 0 ? modbus_strerror(errno) : "a reply");
    return 0;
}

/* FC16 (mask write register) is not served: exception 01, as on RTU. */
static int tcp_unsupported_function(void)
{
    modbus_set_slave(ctx, GATEWAY);
    int n = modbus_mask_write_register(ctx, G_WATCHDOG, 0xFFFF, 0);
    CHECK(n < 0 && errno == EMBXILFUN, "FC16: %s, expected illegal function",
          n < 0 ? modbus_strerror(errno) : "a reply");
    return 0;
}

static int tcp_fc11_gateway(void)
{
    char expected[64];
    snprintf(expected, sizeof expected, "RC-GW %s", version_text);
    uint8_t id[MODBUS_MAX_PDU_LENGTH];
    modbus_set_slave(ctx, GATEWAY);
    int n = modbus_report_slave_id(ctx, sizeof id, id);
    CHECK(n >= 2, "FC11: %s", modbus_strerror(errno));
    CHECK(id[0] == GATEWAY && id[1] == 0xFF, "FC11: server id %u run 0x%02X", id[0], id[1]);
    CHECK(n - 2 == (int)strlen(expected) && memcmp(id + 2, expected, n - 2) == 0,
          "FC11: \"%.*s\", expected \"%s\"", n - 2, (const char *)id + 2, expected);
    return 0;
}

static int fc03_plclink(void)
{
    /* PLCLINK: Modbus frames, CRC errors, exceptions, replies (u32 each), never cleared. */
    uint16_t a[8], b[8];
    if (read_regs(GATEWAY, G_PLCLINK, 8, a) < 0 || read_regs(GATEWAY, G_PLCLINK, 8, b) < 0)
        return -1;
    uint32_t frames_a = (uint32_t)a[0] << 16 | a[1], frames_b = (uint32_t)b[0] << 16 | b[1];
    uint32_t replies_a = (uint32_t)a[6] << 16 | a[7], replies_b = (uint32_t)b[6] << 16 | b[7];
    CHECK(frames_b == frames_a + 1, "PLCLINK frames %u -> %u, expected +1", frames_a, frames_b);
    CHECK(replies_b == replies_a + 1, "PLCLINK replies %u -> %u", replies_a, replies_b);
    return 0;
}

/* ------------------------------------------------------------------------------ invalid */

static uint16_t cmct_before[16], drg1_before[16], posr_before[16];

static int snapshot(uint16_t *cmct, uint16_t *drg1, uint16_t *posr)
{
    for (int unit = 1; unit <= axes; unit++)
        if (read_reg(unit, CMCT, &cmct[unit - 1]) < 0 || read_reg(unit, DRG1, &drg1[unit - 1]) < 0 ||
            read_reg(unit, POSR, &posr[unit - 1]) < 0)
            return -1;
    return 0;
}

static int before_invalid(void)
{
    return snapshot(cmct_before, drg1_before, posr_before);
}

static int x02_unknown_address(void)
{
    uint16_t r[2], v = 1;
    uint8_t bit;
    modbus_set_slave(ctx, 1);
    EXPECT_EXCEPTION(X_ADDRESS, modbus_read_registers(ctx, 0x1234, 1, r), "FC03 0x1234");
    EXPECT_EXCEPTION(X_ADDRESS, modbus_write_register(ctx, 0x1234, 1), "FC06 0x1234");
    EXPECT_EXCEPTION(X_ADDRESS, modbus_write_registers(ctx, 0x1234, 1, &v), "FC10 0x1234");
    EXPECT_EXCEPTION(X_ADDRESS, modbus_write_bit(ctx, 0x0404, 1), "FC05 coil 0x0404");
    EXPECT_EXCEPTION(X_ADDRESS, modbus_read_bits(ctx, 0x0404, 1, &bit), "FC01 coil 0x0404");
    EXPECT_EXCEPTION(X_ADDRESS, modbus_read_input_registers(ctx, DRG1, 1, r), "FC04 DRG1");
    uint16_t four[4] = {0, 1000, 0, 10};
    EXPECT_EXCEPTION(X_ADDRESS, modbus_write_registers(ctx, DIRECT, 4, four), "FC10 0x9900 x4");
    modbus_set_slave(ctx, GATEWAY);
    EXPECT_EXCEPTION(X_ADDRESS, modbus_read_registers(ctx, 0x0050, 1, r), "FC03 unit 63 0x0050");
    EXPECT_EXCEPTION(X_ADDRESS, modbus_read_bits(ctx, COIL_SON, 1, &bit),
                     "FC01 unit 63 (no coils)");
    /* FC02: the slave decodes it, and the map has no discrete inputs, so every address is
     * unknown (02). README's "Modbus functions" does not list FC02 ("anything else answers
     * 01"): this pins down what the gateway does. */
    modbus_set_slave(ctx, 1);
    EXPECT_EXCEPTION(X_ADDRESS, modbus_read_input_bits(ctx, COIL_SON, 1, &bit),
                     "FC02 read discrete inputs");
    return 0;
}

static int x03_bad_value(void)
{
    modbus_set_slave(ctx, 1);
    EXPECT_EXCEPTION(X_VALUE, modbus_write_register(ctx, POSR, 16), "POSR 16");
    EXPECT_EXCEPTION(X_VALUE, modbus_write_register(ctx, DRG1, DRG1_SON | 1 << 7), "DRG1 BKRL");
    EXPECT_EXCEPTION(X_VALUE, modbus_write_register(ctx, PNOW, 1), "write PNOW (read-only)");
    uint16_t beyond[7] = {0, 10001, 0, 10, 0, 10000, 30};
    EXPECT_EXCEPTION(X_VALUE, modbus_write_registers(ctx, DIRECT, 7, beyond),
                     "direct move beyond the stroke");
    uint16_t zero_speed[7] = {0, 1000, 0, 10, 0, 0, 30};
    EXPECT_EXCEPTION(X_VALUE, modbus_write_registers(ctx, DIRECT, 7, zero_speed),
                     "direct move at speed 0");
    modbus_set_slave(ctx, GATEWAY);
    EXPECT_EXCEPTION(X_VALUE, modbus_write_register(ctx, G_WATCHDOG, 10), "WATCHDOG 10");
    EXPECT_EXCEPTION(X_VALUE, modbus_write_register(ctx, G_FAILSAFE, 1), "FAILSAFE 1");
    /* Quantities outside the function's range, which libmodbus refuses to send itself. */
    uint8_t zero[] = {1, 0x03, 0x90, 0x05, 0x00, 0x00};
    uint8_t many[] = {1, 0x03, 0x90, 0x00, 0x00, 126};
    uint8_t coil_value[] = {1, 0x05, 0x04, 0x03, 0x12, 0x34};
    if (raw_exception(zero, sizeof zero, X_VALUE, "FC03 of 0 registers") < 0 ||
        raw_exception(many, sizeof many, X_VALUE, "FC03 of 126 registers") < 0 ||
        raw_exception(coil_value, sizeof coil_value, X_VALUE, "FC05 value 0x1234") < 0)
        return -1;
    return 0;
}

static int x01_unsupported_function(void)
{
    uint16_t r[1], w[1] = {DRG1_SON};
    modbus_set_slave(ctx, 1);
    EXPECT_EXCEPTION(X_FUNCTION, modbus_mask_write_register(ctx, DRG1, 0, DRG1_SON),
                     "FC16 mask write");
    EXPECT_EXCEPTION(X_FUNCTION, modbus_write_and_read_registers(ctx, DRG1, 1, w, DSS1, 1, r),
                     "FC17 read/write registers");
    /* No libmodbus call: FC07 read exception status, FC14 file record, FC08 sub-function 03
     * (ASCII delimiter, serial line §6.1) and an undefined one, FC2B of MEI type 0x0D. */
    uint8_t fc07[] = {1, 0x07};
    uint8_t fc14[] = {1, 0x14, 0x07, 0x06, 0x00, 0x01, 0x00, 0x00, 0x00, 0x01};
    uint8_t sub03[] = {1, 0x08, 0x00, 0x03, 0x0A, 0x00};
    uint8_t sub99[] = {GATEWAY, 0x08, 0x00, 0x99, 0x00, 0x00};
    uint8_t mei0d[] = {1, 0x2B, 0x0D, 0x01, 0x00};
    if (raw_exception(fc07, sizeof fc07, X_FUNCTION, "FC07") < 0 ||
        raw_exception(fc14, sizeof fc14, X_FUNCTION, "FC14") < 0 ||
        raw_exception(sub03, sizeof sub03, X_FUNCTION, "FC08/03") < 0 ||
        raw_exception(sub99, sizeof sub99, X_FUNCTION, "FC08/99") < 0 ||
        raw_exception(mei0d, sizeof mei0d, X_FUNCTION, "FC2B MEI 0x0D") < 0)
        return -1;
    return 0;
}

static int x_fc08_fc2b_bad_data(void)
{
    /* FC08: data other than 0000 is 03. FC2B/0E: an unknown ReadDevId code 03, an unknown
     * object asked individually 02. */
    uint8_t data[] = {1, 0x08, 0x00, 0x0B, 0x00, 0x01};
    uint8_t code5[] = {1, 0x2B, 0x0E, 0x05, 0x00};
    uint8_t object80[] = {GATEWAY, 0x2B, 0x0E, 0x04, 0x80};
    if (raw_exception(data, sizeof data, X_VALUE, "FC08/0B data 0001") < 0 ||
        raw_exception(code5, sizeof code5, X_VALUE, "FC2B ReadDevId 05") < 0 ||
        raw_exception(object80, sizeof object80, X_ADDRESS, "FC2B object 0x80") < 0)
        return -1;
    return 0;
}

static int no_reply_not_served_or_broken(void)
{
    /* A unit the gateway does not serve: no reply (libmodbus times out). */
    uint16_t r[1];
    modbus_set_slave(ctx, NOT_SERVED);
    errno = 0;
    CHECK(modbus_read_registers(ctx, DSS1, 1, r) == -1 && errno == ETIMEDOUT,
          "unit %d answered (%s); it is not served", NOT_SERVED, modbus_strerror(errno));
    /* Broken frames, written as they are: a bad CRC, too short, a reply function code, an
     * FC10 whose byte count disagrees with its quantity (with a good CRC). No reply to the
     * first three; the last is malformed: exception 03. */
    uint16_t errors0, errors1;
    if (diag(GATEWAY, 0x0C, &errors0) < 0)
        return -1;
    uint8_t bad_crc[] = {1, 0x06, 0x0D, 0x00, 0x10, 0x08, 0x00, 0x00};
    uint16_t crc = crc16(bad_crc, 6) ^ 0xFFFF;
    bad_crc[6] = crc & 0xFF;
    bad_crc[7] = crc >> 8;
    CHECK(raw_bytes(bad_crc, sizeof bad_crc, 0.5) == 0, "a frame with a bad CRC was answered");
    uint8_t short_frame[] = {0x55, 0xAA};
    CHECK(raw_bytes(short_frame, sizeof short_frame, 0.5) == 0, "a 2-byte frame was answered");
    uint8_t reply_code[5] = {1, 0x83, 0x02};
    crc = crc16(reply_code, 3);
    reply_code[3] = crc & 0xFF;
    reply_code[4] = crc >> 8;
    CHECK(raw_bytes(reply_code, sizeof reply_code, 0.5) == 0, "function 0x83 was answered");
    if (diag(GATEWAY, 0x0C, &errors1) < 0)
        return -1;
    /* 0C counts bad CRCs only: the 2-byte burst is too short to have one. */
    CHECK((uint16_t)(errors1 - errors0) == 1, "CRC error count %u -> %u, expected +1", errors0,
          errors1);
    uint8_t bad_count[] = {1, 0x10, 0x0D, 0x03, 0x00, 0x01, 0x04, 0x00, 0x05, 0x00, 0x00};
    return raw_exception(bad_count, sizeof bad_count, X_VALUE, "FC10 byte count 4 for 1 register");
}

static int state_untouched(void)
{
    uint16_t cmct[16], drg1[16], posr[16];
    if (snapshot(cmct, drg1, posr) < 0)
        return -1;
    for (int i = 0; i < axes; i++) {
        CHECK(cmct[i] == cmct_before[i], "unit %d CMCT %u -> %u: a refused request was taken",
              i + 1, cmct_before[i], cmct[i]);
        CHECK(drg1[i] == drg1_before[i] && posr[i] == posr_before[i],
              "unit %d DRG1/POSR 0x%04X/%u -> 0x%04X/%u", i + 1, drg1_before[i], posr_before[i],
              drg1[i], posr[i]);
    }
    return 0;
}

/* ------------------------------------------------------------------------------ main */

int main(int argc, char **argv)
{
    int debug = 0, arg = 1;
    for (; arg < argc && argv[arg][0] == '-'; arg++) {
        if (strcmp(argv[arg], "-v") == 0)
            debug = 1;
        else
            break;
    }
    if (argc - arg < 4) {
        fprintf(stderr, "usage: %s [-v] DEVICE VERSION AXES valid|invalid|tcp|tcp-axes...\n", argv[0]);
        return 2;
    }
    const char *device = argv[arg];
    snprintf(version_text, sizeof version_text, "%s", argv[arg + 1]);
    if (sscanf(version_text, "%u.%u.%u", &version_major, &version_minor, &version_patch) != 3) {
        fprintf(stderr, "VERSION must be major.minor.patch: %s\n", version_text);
        return 2;
    }
    axes = atoi(argv[arg + 2]);
    if (axes < 2 || axes > 16) {
        fprintf(stderr, "AXES must be 2-16\n");
        return 2;
    }

    printf("# libmodbus %s on %s\n", LIBMODBUS_VERSION_STRING, device);
    if (strncmp(device, "tcp:", 4) == 0) {
        char host[64];
        int port = 0;
        const char *colon = strrchr(device + 4, ':');
        if (colon == NULL || (size_t)(colon - device - 4) >= sizeof host ||
            (port = atoi(colon + 1)) <= 0) {
            fprintf(stderr, "DEVICE tcp:HOST:PORT: %s\n", device);
            return 2;
        }
        memcpy(host, device + 4, (size_t)(colon - device - 4));
        host[colon - device - 4] = '\0';
        ctx = modbus_new_tcp(host, port);
    } else {
        ctx = modbus_new_rtu(device, 115200, 'N', 8, 1);
    }
    if (ctx == NULL || modbus_connect(ctx) < 0) {
        printf("FAIL connect: %s\n", modbus_strerror(errno));
        return 1;
    }
    modbus_set_debug(ctx, debug);
    /* Generous: a reply takes a few ms, but a loaded machine may stall the gateway a while. */
    modbus_set_response_timeout(ctx, 2, 0);
    modbus_set_byte_timeout(ctx, 1, 0);

    for (int g = arg + 3; g < argc; g++) {
        if (strcmp(argv[g], "valid") == 0) {
            run("axes-online", axes_online);
            run("fc03-gateway-version", fc03_gateway_version);
            run("fc03-gateway-settings", fc03_gateway_settings);
            run("fc06-fc03-gateway-watchdog", fc06_fc03_gateway_watchdog);
            run("fc03-axis-status", fc03_axis_status);
            run("fc04-axis-status", fc04_axis_status);
            run("fc06-servo-off-on", fc06_servo_off_on);
            run("fc01-coil-son-stop", fc01_coil_son);
            run("fc05-coil-home", fc05_coil_home);
            run("fc05-fc0f-coil-stp", fc05_fc0f_coil_stp);
            run("fc10-direct-move", fc10_direct_move);
            run("fc10-fc06-posr", fc10_posr);
            run("fc08-00-echo", fc08_echo);
            run("fc08-counters", fc08_counters);
            run("fc2b-0e-device-id", fc2b_device_id);
            run("fc11-report-server-id", fc11_report_server_id);
            run("fc03-plclink-counts", fc03_plclink);
        } else if (strcmp(argv[g], "tcp") == 0) {
            run("tcp-fc03-gateway-version", fc03_gateway_version);
            run("tcp-fc06-fc03-gateway-watchdog", fc06_fc03_gateway_watchdog);
            run("tcp-unit-ff-is-the-gateway", tcp_direct_unit);
            run("tcp-exception-0a-unserved-unit", tcp_unserved_unit);
            run("tcp-exception-01-unsupported-function", tcp_unsupported_function);
            run("tcp-fc11-report-server-id", tcp_fc11_gateway);
        } else if (strcmp(argv[g], "tcp-axes") == 0) {
            run("tcp-axes-online", axes_online);
            run("tcp-fc03-axis-status", fc03_axis_status);
            run("tcp-fc06-servo-off-on", fc06_servo_off_on);
            run("tcp-fc05-coil-home", fc05_coil_home);
            run("tcp-fc10-direct-move", fc10_direct_move);
        } else if (strcmp(argv[g], "invalid") == 0) {
            run("snapshot", before_invalid);
            run("exception-02-unknown-address", x02_unknown_address);
            run("exception-03-bad-value", x03_bad_value);
            run("exception-01-unsupported-function", x01_unsupported_function);
            run("exception-fc08-fc2b-bad-data", x_fc08_fc2b_bad_data);
            run("no-reply-unserved-unit-and-broken-frames", no_reply_not_served_or_broken);
            run("state-untouched", state_untouched);
        } else {
            fprintf(stderr, "unknown group %s\n", argv[g]);
            failures++;
        }
    }
    modbus_close(ctx);
    modbus_free(ctx);
    printf("# libmodbus: %d scenarios, %d failed\n", scenarios, failures);
    return failures ? 1 : 0;
}
