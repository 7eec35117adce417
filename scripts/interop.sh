#!/usr/bin/env bash
# Interop: Modbus RTU and TCP masters other than pymodbus drive rc-gateway-host (the firmware's
# engine and register map on the PC) through a pseudo-terminal, with simulated controllers behind
# it:
#   - libmodbus, through tests/interop/libmodbus_client.c: every function the gateway serves
#     (raw requests for FC08 and FC2B, which libmodbus has no call for), exceptions 01/02/03,
#     broken frames;
#   - mbpoll, the command-line master, as far as its options can express the same scenarios
#     (what it cannot send is listed as `skip <name>: <why>`).
# Each master gets a fresh gateway (3 axes, watchdog off). After each master's refused requests,
# the simulator's own view (`stats` on the control line: commands the controllers received,
# motion, position) must be unchanged: nothing refused or malformed reaches the bus.
#
# The same scenarios then run against the real firmware ELF in QEMU (`--target firmware`; both by
# default): tests/pyshared/emu.py starts QEMU with rc-sim on the bus, commissions it as a
# Modbus-only installation (3 axes, watchdog off, no PIO axis; stop chain closed from power-up)
# and bridges the firmware's PLC line to a pseudo-terminal for the masters. There the
# controllers' view is rc-sim's frame log (commands other than status and position polls), and
# the refusals are counted by the gateway's PLCLINK registers.
#
# Over Modbus TCP, libmodbus (`modbus_new_tcp`) and `mbpoll -m tcp` drive rc-gateway-host
# --modbus-tcp (host) and the network firmware in QEMU's mps2-an386 (firmware: rc-gateway-mps2,
# the Ethernet board's network task over an emulated LAN9118; it has no bus, so the axes'
# scenarios run on the host only): unit 0xFF, exception 0A for a unit nobody serves, the gateway
# unit's reads and writes, FC11, the axes.
#
#   scripts/interop.sh [--target host|firmware|all]
#
# Installs what it needs when missing: libmodbus-dev, mbpoll, pkg-config (and gcc) with apt-get
# (through sudo unless root), the pinned Rust toolchain; for the firmware, QEMU and the emulator
# build as scripts/emu-test.sh does. One line per scenario, `ok <target>/<name>` or
# `FAIL <target>/<name>: <why>`; exit status 1 if any failed. Every wait is bounded; nothing is
# timed.
set -euo pipefail
cd "$(dirname "$0")/.."

AXES=3
GATEWAY=63
target=${CARGO_TARGET_DIR:-target}

targets=(host firmware)
if [[ ${1:-} == --target ]]; then
    case ${2:-} in
    host | firmware) targets=("$2") ;;
    all) ;;
    *) echo "usage: $0 [--target host|firmware|all]" >&2 && exit 2 ;;
    esac
fi

# ---------------------------------------------------------------------------------- set-up

missing=()
command -v pkg-config >/dev/null || missing+=(pkg-config)
pkg-config --exists libmodbus 2>/dev/null || missing+=(libmodbus-dev)
command -v mbpoll >/dev/null || missing+=(mbpoll)
command -v gcc >/dev/null || missing+=(gcc libc6-dev)
if ((${#missing[@]})); then
    sudo=()
    [[ $(id -u) == 0 ]] || sudo=(sudo)
    apt() { ${sudo[@]+"${sudo[@]}"} env DEBIAN_FRONTEND=noninteractive apt-get "$@"; }
    echo "interop: installing ${missing[*]}" >&2
    if ! apt install -y --no-install-recommends "${missing[@]}"; then
        apt update
        apt install -y --no-install-recommends "${missing[@]}"
    fi
fi

rustup toolchain install >/dev/null
cargo build --locked -p rc-tools --bin rc-gateway-host
gateway_bin="$target/debug/rc-gateway-host"
mkdir -p "$target/interop"
client="$target/interop/libmodbus_client"
# shellcheck disable=SC2046 # pkg-config's flags are separate words
gcc -std=c11 -D_POSIX_C_SOURCE=200809L -Wall -Wextra -O2 -o "$client" \
    tests/interop/libmodbus_client.c $(pkg-config --cflags --libs libmodbus)
# The version the gateway reports (VERSION, FC11, FC2B object 02): the protocol crate's.
version=$(sed -n 's/^version = "\([0-9]*\.[0-9]*\.[0-9]*\)".*/\1/p' protocol/Cargo.toml | head -n 1)
[[ -n $version ]] || { echo "interop: no version in protocol/Cargo.toml" >&2; exit 1; }

failures=0
why=""

# ---------------------------------------------------------------------------------- gateway

gateway_pid=""
gateway_log=""
kind=host
bus_log=""

# A fresh gateway of the current kind ($kind) on a new pseudo-terminal: its path in $pty.
start_gateway() {
    if [[ $kind == firmware ]]; then
        start_firmware "$1"
    else
        start_host "$1"
    fi
}

# The firmware in QEMU (tests/pyshared/emu.py), commissioned for Modbus only.
start_firmware() {
    gateway_log="$target/interop/firmware-$1.log"
    coproc GW { exec "$python" tests/pyshared/emu.py "$elf" --axes "0-$((AXES - 1))" --modbus-only \
        --workdir "$target/interop/firmware-$1" 2>"$gateway_log"; }
    gateway_pid=$GW_PID
    gw_out=${GW[0]}
    gw_in=${GW[1]}
    local line="" log=""
    if ! read -r -t 180 -u "$gw_out" line || [[ $line != "PLC /dev/"* ]] ||
        ! read -r -t 10 -u "$gw_out" log || [[ $log != "BUS LOG "* ]]; then
        echo "interop: the firmware in QEMU did not start: '$line'" >&2
        tail -n 30 "$gateway_log" >&2 || true
        exit 1
    fi
    pty=${line#PLC }
    bus_log=${log#BUS LOG }
    echo "# firmware in QEMU (pid $gateway_pid, $AXES simulated axes): PLC line $pty"
}

# A fresh rc-gateway-host on a new pseudo-terminal: its path in $pty; control lines through the
# coprocess' pipes.
start_host() {
    gateway_log="$target/interop/rc-gateway-host-$1.log"
    coproc GW { exec "$gateway_bin" --plc-pty --sim "$AXES" --points --watchdog-ms 0 --log 2>"$gateway_log"; }
    gateway_pid=$GW_PID
    gw_out=${GW[0]}
    gw_in=${GW[1]}
    local line=""
    if ! read -r -t 20 -u "$gw_out" line || [[ $line != "PLC /dev/"* ]]; then
        echo "interop: rc-gateway-host did not start: '$line'" >&2
        tail -n 20 "$gateway_log" >&2 || true
        exit 1
    fi
    pty=${line#PLC }
    echo "# rc-gateway-host (pid $gateway_pid, $AXES simulated axes): PLC line $pty"
}

stop_gateway() {
    [[ -n $gateway_pid ]] || return 0
    if [[ $kind == firmware ]]; then
        # emu.py ends at the end of its input, and kills QEMU and rc-sim.
        exec {gw_in}>&- 2>/dev/null || true
    else
        { echo quit >&"$gw_in"; } 2>/dev/null || true
    fi
    local i
    for i in $(seq 50); do
        kill -0 "$gateway_pid" 2>/dev/null || break
        sleep 0.1
    done
    if kill -TERM "$gateway_pid" 2>/dev/null; then
        sleep 1
    fi
    kill -KILL "$gateway_pid" 2>/dev/null || true
    wait "$gateway_pid" 2>/dev/null || true
    gateway_pid=""
}
trap stop_gateway EXIT

# One control line; its one-line JSON answer in $answer.
control() {
    echo "$1" >&"$gw_in"
    answer=""
    if ! read -r -t 10 -u "$gw_out" answer; then
        echo "interop: no answer to '$1' on the control line" >&2
        exit 1
    fi
}

# JSON fields of $answer (compact, from serde_json), joined with commas.
field() { grep -o "\"$1\":[^,}]*" <<<"$answer" | cut -d: -f2 | paste -sd, -; }
exceptions() { grep -o '"exceptions":\[[0-9,]*\]' <<<"$answer" | sed 's/.*\[\(.*\)\]/\1/'; }

# What the simulated controllers saw: commands received (the frames other than the status and
# position polls), whether they move, where they are.
bus_view() {
    if [[ $kind == firmware ]]; then
        # rc-sim's log: the commands that change something; the refusals: PLCLINK (u32 each:
        # frames, CRC errors, exceptions, replies, other units, broadcasts, malformed).
        bus="commands=$(grep '>> Request' "$bus_log" | grep -cvE 'command: (Status|ReadMemory)')"
        mb_read $GATEWAY 4 0x0510 14 >/dev/null || { echo "interop: PLCLINK unreadable: $why" >&2 && exit 1; }
        counts="$((values[4] << 16 | values[5]))"
        crc=$((values[2] << 16 | values[3]))
        ignored=$((values[8] << 16 | values[9]))
        return
    fi
    control stats
    bus="commands=$(field commands) moving=$(field moving) position=$(field position)"
    counts=$(exceptions)
    crc=$(field crc_errors)
    ignored=$(field ignored)
}

report() { # name, status of the check (0 ok), why
    if (($2 == 0)); then
        echo "ok $kind/$1"
    else
        echo "FAIL $kind/$1: $3"
        failures=$((failures + 1))
    fi
}

# After a group of refused requests: nothing reached the bus, and the gateway counted the
# refusals (exception replies by code 01-04; CRC errors; frames to units it does not serve).
check_bus() { # master, min increase of exceptions 01, 02, 03, of CRC errors, of ignored
    local before=$bus before_counts=$counts before_crc=$crc before_ignored=$ignored
    bus_view
    local same=0
    [[ $bus == "$before" ]] || same=1
    report "$1-nothing-reached-the-bus" $same "$before -> $bus"
    echo "# $1: simulated controllers saw $bus"
    local b a i ok=0
    IFS=, read -r -a b <<<"$before_counts"
    IFS=, read -r -a a <<<"$counts"
    local want=("$2" "$3" "$4")
    if [[ $kind == firmware ]]; then
        # PLCLINK counts exceptions of every code together.
        ((a[0] - b[0] >= $2 + $3 + $4)) || ok=1
    else
        for i in 0 1 2; do
            ((a[i] - b[i] >= want[i])) || ok=1
            ((want[i] > 0 || a[i] == b[i])) || ok=1
        done
    fi
    ((crc - before_crc == $5)) || ok=1
    ((ignored - before_ignored >= $6)) || ok=1
    report "$1-refusals-counted" $ok \
        "exceptions 01-04 [$before_counts] -> [$counts], expected +$2/+$3/+$4 or more (+0 exactly where 0); CRC errors $before_crc -> $crc (+$5); ignored $before_ignored -> $ignored (+$6 or more)"
}

gateway_failed() {
    echo "---- $gateway_log (last lines) ----"
    tail -n 60 "$gateway_log" || true
}

# ---------------------------------------------------------------------------------- libmodbus

# The C client on one group of scenarios; its FAIL lines (at least one if it fails) counted.
run_client() {
    local out="$target/interop/libmodbus-$1.out" status=0 failed
    timeout --kill-after=10 300 "$client" "$pty" "$version" "$AXES" "$1" |
        sed -u "s#^\(ok\|FAIL\|skip\) #\1 $kind/#" | tee "$out" || status=$?
    failed=$(grep -c '^FAIL' "$out" || true)
    ((failed > 0 || status == 0)) || failed=1
    failures=$((failures + failed))
}

libmodbus_suite() {
    start_gateway libmodbus
    failed_before=$failures
    run_client valid
    bus_view
    run_client invalid
    # Exceptions 01 x7, 02 x11, 03 x11, one bad CRC, one unit not served.
    check_bus libmodbus 7 11 11 1 1
    ((failures == failed_before)) || gateway_failed
    stop_gateway
}

# ---------------------------------------------------------------------------------- mbpoll

# -0: addresses as on the wire (PDU), -1: one poll, -o 2: generous time-out, 8N1 as the gateway.
MB=(mbpoll -m rtu -b 115200 -P none -0 -1 -o 2)

fail() {
    why="$*"
    return 1
}

scenario() { # name, function
    why=""
    if "$2"; then
        echo "ok $kind/$1"
    else
        echo "FAIL $kind/$1: ${why:-failed}"
        failures=$((failures + 1))
    fi
}

skip() { echo "skip $kind/$1: $2"; }

# mbpoll ARGS...: its output in $mb_out, its exit status in $mb_rc.
mb() {
    mb_rc=0
    mb_out=$(timeout --kill-after=5 60 "${MB[@]}" "$@" 2>&1) || mb_rc=$?
}

mb_error() { grep -m 1 -i 'fail\|error\|range' <<<"$mb_out" || echo "exit status $mb_rc"; }

# mb_read UNIT TYPE REF COUNT [OPTION...]: the values in ${values[@]} ("60000 (-5536)" reads
# 60000).
mb_read() {
    mb -a "$1" -t "$2" -r "$3" -c "$4" "${@:5}" "$pty"
    ((mb_rc == 0)) || fail "read unit $1 -t $2 $3 x$4: $(mb_error)" || return 1
    mapfile -t values < <(sed -n 's/^\[[0-9]*\]:[[:space:]]*\([^ ]*\).*/\1/p' <<<"$mb_out")
    ((${#values[@]} == $4)) || fail "read unit $1 $3: ${#values[@]} values, expected $4" || return 1
}

# mb_write UNIT TYPE REF VALUE...: one value is FC05/FC06, more are FC0F/FC10.
mb_write() {
    local n=$(($# - 3))
    mb -a "$1" -t "$2" -r "$3" "$pty" -- "${@:4}"
    if ((mb_rc != 0)) || ! grep -q "^Written $n references" <<<"$mb_out"; then
        fail "write unit $1 -t $2 $3 = ${*:4}: $(mb_error)"
    fi
}

# mb_refused EXCEPTION-TEXT UNIT TYPE REF [VALUE...]: the read (no value) or write fails, and
# mbpoll shows the exception.
mb_refused() {
    mb -a "$2" -t "$3" -r "$4" "$pty" -- "${@:5}"
    if ((mb_rc == 0)) || ! grep -q "failed: $1" <<<"$mb_out"; then
        fail "unit $2 -t $3 $4 ${*:5}: '$(mb_error)', expected '$1'"
    fi
}

# mb_wait UNIT REF MASK WANT WHAT: polls FC03 until (value & MASK) == WANT, at most 20 s.
mb_wait() {
    local deadline=$((SECONDS + 20))
    while :; do
        if mb_read "$1" 4 "$2" 1 && (((values[0] & $3) == $4)); then
            return 0
        fi
        ((SECONDS < deadline)) || fail "timed out waiting for $5 (unit $1 $2 = ${values[0]:-?})" || return 1
        sleep 0.05
    done
}

# settle UNIT: the axis' last command is done (CMST 2, CMER 0).
settle() {
    local deadline=$((SECONDS + 20))
    while :; do
        mb_read "$1" 4 0x9F00 2 || return 1
        ((values[0] == 2 || values[0] == 3)) && break
        ((SECONDS < deadline)) || fail "unit $1: command did not settle (CMST ${values[0]})" || return 1
        sleep 0.05
    done
    ((values[0] == 2 && values[1] == 0)) || fail "unit $1: CMST ${values[0]} CMER ${values[1]}, want 2, 0"
}

# Axis registers and bits (docs/plc.md: register map).
PNOW=0x9000 DSS1=0x9005 CMCT=0x9F03 DRG1=0x0D00 POSR=0x0D03 DIRECT=0x9900
COIL_SON=0x0403 COIL_STP=0x040A COIL_HOME=0x040B COIL_STOP=0x042C
SON=$((1 << 12)) SV=$((1 << 12)) PWR=$((1 << 13)) STP=$((1 << 5)) HEND=$((1 << 4)) PEND=$((1 << 3))
ALM_N=$((1 << 14))

mb_axes_online() {
    local deadline=$((SECONDS + 20))
    while :; do
        # An address list: mbpoll polls units 1, 2 and 3 in turn.
        mb -a 1,2,3 -t 4 -r 0x9F02 "$pty"
        [[ $(sed -n 's/^\[[0-9]*\]:[[:space:]]*//p' <<<"$mb_out" | paste -sd, -) == 1,1,1 ]] && return 0
        ((SECONDS < deadline)) || fail "LINK of units 1-3 not all 1: $mb_out" || return 1
        sleep 0.1
    done
}

mb_gateway_version() {
    IFS=. read -r major minor patch <<<"$version"
    mb_read $GATEWAY 4 0 2 || return 1
    ((values[0] == (major << 8 | minor) && values[1] == patch)) ||
        fail "VERSION ${values[*]}, expected $((major << 8 | minor)) $patch ($version)"
}

mb_gateway_settings() {
    # FAILSAFE FSCOUNT WATCHDOG BUSBAUD BUSRTIM: no trip, --watchdog-ms 0, 115200 bit/s, 3 ms.
    mb_read $GATEWAY 4 4 5 || return 1
    [[ ${values[*]} == "0 0 0 1152 3" ]] || fail "FAILSAFE..BUSRTIM = ${values[*]}, expected 0 0 0 1152 3" || return 1
    # AXISCFG of axis 1 (0x0108): enabled, lead 8.00 mm, home at the motor end (7), -, stroke 100.00 mm.
    mb_read $GATEWAY 4 0x0108 6 || return 1
    [[ "${values[0]} ${values[1]} ${values[2]} ${values[4]} ${values[5]}" == "1 800 7 0 10000" ]] ||
        fail "AXISCFG[1] = ${values[*]}, expected 1 800 7 - 0 10000"
}

mb_gateway_watchdog() {
    mb_write $GATEWAY 4 6 60000 && mb_read $GATEWAY 4 6 1 || return 1
    ((values[0] == 60000)) || fail "WATCHDOG reads ${values[0]} after writing 60000" || return 1
    mb_write $GATEWAY 4 6 0 && mb_read $GATEWAY 4 6 1 || return 1
    ((values[0] == 0)) || fail "WATCHDOG reads ${values[0]} after writing 0"
}

mb_axis_status() {
    local unit
    for unit in $(seq "$AXES"); do
        mb_read "$unit" 4 $PNOW 8 || return 1
        # PNOW(2) ALMC DIPM DOPM DSS1 DSS2 DSSE
        ((values[2] == 0)) || fail "unit $unit ALMC ${values[2]}, expected 0" || return 1
        ((values[4] & ALM_N)) || fail "unit $unit DOPM ${values[4]}: *ALM off" || return 1
        ((values[5] & PWR)) || fail "unit $unit DSS1 ${values[5]}: PWR off" || return 1
        ((!(values[5] & HEND))) || fail "unit $unit DSS1 ${values[5]}: HEND before homing" || return 1
        ((values[6] == 0)) || fail "unit $unit DSS2 ${values[6]}, expected 0 (always)" || return 1
    done
}

mb_fc04_status() {
    mb_read 1 3 0x9F00 4 || return 1
    local input=("${values[@]}")
    mb_read 1 4 0x9F00 4 || return 1
    ((input[2] == 1)) || fail "FC04 LINK ${input[2]}, expected 1" || return 1
    ((input[3] == values[3])) || fail "FC04 CMCT ${input[3]}, FC03 CMCT ${values[3]}"
}

mb_servo_off_on() {
    # SON is a level: the first write of SON is a command even with the servo on already.
    mb_read 1 4 $CMCT 1 || return 1
    local count0=${values[0]}
    mb_write 1 4 $DRG1 $SON && settle 1 || return 1
    mb_write 1 4 $DRG1 0 && settle 1 && mb_wait 1 $DSS1 $SV 0 "DSS1 SV off" || return 1
    mb_write 1 4 $DRG1 $SON && mb_read 1 4 $DRG1 1 || return 1
    ((values[0] == SON)) || fail "DRG1 reads ${values[0]} after writing $SON" || return 1
    settle 1 && mb_wait 1 $DSS1 $SV $SV "DSS1 SV on" && mb_read 1 4 $CMCT 1 || return 1
    ((values[0] - count0 == 3)) || fail "CMCT $count0 -> ${values[0]}: three commands taken"
}

mb_coils_read() {
    mb_read 1 0 $COIL_SON 1 || return 1
    ((values[0] == 1)) || fail "SON coil reads ${values[0]} with DRG1 SON set" || return 1
    mb_read 1 0 $COIL_STOP 1 || return 1
    ((values[0] == 0)) || fail "STOP coil reads ${values[0]}, documented to read 0"
}

mb_coil_home() {
    mb_write 1 0 $COIL_HOME 0 && mb_write 1 0 $COIL_HOME 1 || return 1
    mb_wait 1 $DSS1 $HEND $HEND "DSS1 HEND" && settle 1 && mb_write 1 0 $COIL_HOME 0 || return 1
    # PNOW as one 32-bit value, high word first (-B).
    mb_read 1 4:int $PNOW 1 -B || return 1
    ((values[0] == 0)) || fail "PNOW ${values[0]} after homing, expected 0"
}

mb_coils_stp() {
    # FC05 STP on; FC01 reads it; FC0F of two coils (STP, HOME) clears both.
    mb_write 1 0 $COIL_STP 1 && mb_read 1 0 $COIL_STP 1 || return 1
    ((values[0] == 1)) || fail "STP coil reads ${values[0]} after writing 1" || return 1
    mb_wait 1 $DSS1 $STP $STP "DSS1 STP on" || return 1
    mb_write 1 0 $COIL_STP 0 0 && mb_read 1 0 $COIL_STP 2 || return 1
    [[ ${values[*]} == "0 0" ]] || fail "STP HOME coils read ${values[*]} after FC0F 0 0" || return 1
    mb_wait 1 $DSS1 $STP 0 "DSS1 STP off"
}

mb_direct_move() {
    # FC10 of 7 registers at 0x9900: 25.00 mm, band 0.10 mm, 100.00 mm/s, 0.30 G.
    mb_write 1 4 $DIRECT 0 2500 0 10 0 10000 30 && settle 1 && mb_wait 1 $DSS1 $PEND $PEND "DSS1 PEND" || return 1
    mb_read 1 4:int $PNOW 1 -B || return 1
    ((values[0] == 2500)) || fail "PNOW ${values[0]} after the move, expected 2500"
}

mb_posr() {
    mb_write 2 4 $POSR 3 && mb_read 2 4 $POSR 1 || return 1
    ((values[0] == 3)) || fail "POSR reads ${values[0]} after writing 3" || return 1
    mb_write 2 4 $POSR 0 && mb_read 2 4 $POSR 1 || return 1
    ((values[0] == 0)) || fail "POSR reads ${values[0]} after writing 0"
}

mb_report_server_id() {
    local unit id
    for unit in $GATEWAY 1; do
        mb -a "$unit" -u "$pty"
        ((mb_rc == 0)) || fail "unit $unit: $(mb_error)" || return 1
        id=$(printf '0x%02X' "$unit")
        grep -q "^Id *: $id\$" <<<"$mb_out" || fail "unit $unit: server id: $(grep '^Id' <<<"$mb_out")" || return 1
        grep -q '^Status: On$' <<<"$mb_out" || fail "unit $unit: run indicator: $(grep '^Status' <<<"$mb_out")" || return 1
        grep -q "^Data *: RC-GW $version\$" <<<"$mb_out" || fail "unit $unit: $(grep '^Data' <<<"$mb_out"), expected RC-GW $version" || return 1
    done
}

mb_plclink() {
    # PLCLINK: Modbus frames, CRC errors, exceptions, replies (u32 each). One mbpoll run with
    # -1 sends one request, so two runs see one more frame and one more reply.
    mb_read $GATEWAY 4 0x0510 8 || return 1
    local a=("${values[@]}")
    mb_read $GATEWAY 4 0x0510 8 || return 1
    local frames=$(((values[0] << 16 | values[1]) - (a[0] << 16 | a[1])))
    local replies=$(((values[6] << 16 | values[7]) - (a[6] << 16 | a[7])))
    ((frames == 1 && replies == 1)) ||
        fail "PLCLINK ${a[*]} -> ${values[*]}: +$frames frames, +$replies replies, expected +1 +1"
}

mb_snapshot() { # the name of an array: CMCT, DRG1, POSR of every axis
    local -n into=$1
    into=()
    local unit
    for unit in $(seq "$AXES"); do
        mb_read "$unit" 4 $CMCT 1 || return 1
        into+=("${values[0]}")
        mb_read "$unit" 4 $DRG1 1 || return 1
        into+=("${values[0]}")
        mb_read "$unit" 4 $POSR 1 || return 1
        into+=("${values[0]}")
    done
}

state_before=()
state_after=()
mb_before() { mb_snapshot state_before; }

mb_unknown_address() {
    local A="Illegal data address"
    mb_refused "$A" 1 4 0x1234 &&
        mb_refused "$A" 1 4 0x1234 1 &&
        mb_refused "$A" 1 4 0x1234 1 2 &&
        mb_refused "$A" 1 0 0x0404 1 &&
        mb_refused "$A" 1 0 0x0404 &&
        mb_refused "$A" 1 3 $DRG1 &&
        mb_refused "$A" 1 4 $DIRECT 0 1000 0 10 &&
        mb_refused "$A" $GATEWAY 4 0x0050 &&
        mb_refused "$A" $GATEWAY 0 $COIL_SON &&
        # FC02: no discrete inputs in the map, every address unknown (docs/plc.md's function list
        # does not name FC02).
        mb_refused "$A" 1 1 $COIL_SON
}

mb_bad_value() {
    local V="Illegal data value"
    mb_refused "$V" 1 4 $POSR 16 &&
        mb_refused "$V" 1 4 $DRG1 $((SON | 1 << 7)) &&
        mb_refused "$V" 1 4 $PNOW 1 &&
        mb_refused "$V" 1 4 $DIRECT 0 10001 0 10 0 10000 30 &&
        mb_refused "$V" 1 4 $DIRECT 0 1000 0 10 0 0 30 &&
        mb_refused "$V" $GATEWAY 4 6 10 &&
        mb_refused "$V" $GATEWAY 4 4 1
}

mb_unserved_unit() {
    mb -a 20 -t 4 -r $DSS1 "$pty"
    if ((mb_rc == 0)) || ! grep -q "timed out" <<<"$mb_out"; then
        fail "unit 20 (not served): '$(mb_error)', expected a time-out"
    fi
}

mb_untouched() {
    mb_snapshot state_after || return 1
    [[ ${state_after[*]} == "${state_before[*]}" ]] ||
        fail "CMCT DRG1 POSR per axis ${state_before[*]} -> ${state_after[*]}"
}

mbpoll_suite() {
    start_gateway mbpoll
    failed_before=$failures
    echo "# mbpoll $(mbpoll -V 2>&1 | head -n 1) on $pty"
    scenario axes-online mb_axes_online
    scenario fc03-gateway-version mb_gateway_version
    scenario fc03-gateway-settings mb_gateway_settings
    scenario fc06-fc03-gateway-watchdog mb_gateway_watchdog
    scenario fc03-axis-status mb_axis_status
    scenario fc04-axis-status mb_fc04_status
    scenario fc06-servo-off-on mb_servo_off_on
    scenario fc01-coil-son-stop mb_coils_read
    scenario fc05-coil-home mb_coil_home
    scenario fc05-fc0f-coil-stp mb_coils_stp
    scenario fc10-direct-move mb_direct_move
    scenario fc06-posr mb_posr
    skip fc10-fc06-posr "mbpoll sends one value with FC06, never FC10 of one register (tested with FC06 only)"
    skip fc08-00-echo "mbpoll has no option for FC08 Diagnostics"
    skip fc08-counters "mbpoll has no option for FC08 Diagnostics"
    skip fc2b-0e-device-id "mbpoll has no option for FC2B/0E Read Device Identification (-u is FC11)"
    scenario fc11-report-server-id mb_report_server_id
    scenario fc03-plclink-counts mb_plclink
    bus_view
    scenario snapshot mb_before
    scenario exception-02-unknown-address mb_unknown_address
    scenario exception-03-bad-value mb_bad_value
    skip exception-01-unsupported-function "every function mbpoll can send (01 02 03 04 05 06 0F 10 11) is served (FC02 answers 02: no discrete inputs); it has no option for FC07, FC14, FC16, FC17 or another FC08/FC2B"
    skip exception-fc08-fc2b-bad-data "mbpoll cannot send FC08 or FC2B"
    skip broken-frames "mbpoll always sends a correct CRC and refuses quantities outside 1-125 itself"
    scenario no-reply-unserved-unit mb_unserved_unit
    scenario state-untouched mb_untouched
    # Exceptions 02 x10, 03 x7; no 01 (mbpoll cannot send an unsupported function); no bad CRC.
    check_bus mbpoll 0 10 7 0 1
    ((failures == failed_before)) || gateway_failed
    stop_gateway
}

# ---------------------------------------------------------------------------------- Modbus TCP

tcp_port=""

# A fresh gateway listening on Modbus TCP: its port in $tcp_port.
start_tcp_gateway() {
    gateway_log="$target/interop/tcp-$kind.log"
    if [[ $kind == firmware ]]; then
        tcp_port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
        qemu-system-arm -M mps2-an386 -nographic -monitor none -serial null -icount shift=auto \
            -semihosting-config enable=on,target=native \
            -nic "user,hostfwd=tcp:127.0.0.1:$tcp_port-:502" -kernel "$net_elf" \
            >"$gateway_log" 2>&1 </dev/null &
        gateway_pid=$!
        local i
        for i in $(seq 600); do
            grep -q '^ready' "$gateway_log" && break
            sleep 0.2
        done
        grep -q '^ready' "$gateway_log" || { echo "interop: the network firmware did not start" >&2 && tail -n 20 "$gateway_log" >&2 && exit 1; }
        echo "# network firmware in QEMU mps2-an386 (pid $gateway_pid): Modbus TCP on 127.0.0.1:$tcp_port"
        return
    fi
    coproc GW { exec "$gateway_bin" --modbus-tcp 127.0.0.1:0 --sim "$AXES" --points --watchdog-ms 0 --no-control 2>"$gateway_log"; }
    gateway_pid=$GW_PID
    local line=""
    if ! read -r -t 20 -u "${GW[0]}" line || [[ $line != "TCP "* ]]; then
        echo "interop: rc-gateway-host --modbus-tcp did not start: '$line'" >&2
        exit 1
    fi
    tcp_port=${line##*:}
    echo "# rc-gateway-host (pid $gateway_pid, $AXES simulated axes): Modbus TCP on 127.0.0.1:$tcp_port"
}

stop_tcp_gateway() {
    [[ -n $gateway_pid ]] || return 0
    kill -TERM "$gateway_pid" 2>/dev/null || true
    local i
    for i in $(seq 50); do
        kill -0 "$gateway_pid" 2>/dev/null || break
        sleep 0.1
    done
    kill -KILL "$gateway_pid" 2>/dev/null || true
    wait "$gateway_pid" 2>/dev/null || true
    gateway_pid=""
}

# mbpoll over TCP: -m tcp -p PORT, the rest as on RTU (-0 PDU addresses, one poll).
MBT=(mbpoll -m tcp -0 -1 -o 2)
mbt() {
    mb_rc=0
    mb_out=$(timeout --kill-after=5 60 "${MBT[@]}" -p "$tcp_port" "$@" 127.0.0.1 2>&1) || mb_rc=$?
}

mbt_write() { # UNIT REF VALUE: FC06
    mb_rc=0
    mb_out=$(timeout --kill-after=5 60 "${MBT[@]}" -p "$tcp_port" -a "$1" -t 4 -r "$2" 127.0.0.1 -- "$3" 2>&1) || mb_rc=$?
    if ((mb_rc != 0)) || ! grep -q "^Written 1 references" <<<"$mb_out"; then
        fail "write unit $1 $2 = $3: $(mb_error)"
    fi
}

mbt_read() { # UNIT TYPE REF COUNT: ${values[@]}
    mbt -a "$1" -t "$2" -r "$3" -c "$4"
    ((mb_rc == 0)) || fail "read unit $1 $3 x$4: $(mb_error)" || return 1
    mapfile -t values < <(sed -n 's/^\[[0-9]*\]:[[:space:]]*\([^ ]*\).*/\1/p' <<<"$mb_out")
    ((${#values[@]} == $4)) || fail "read unit $1 $3: ${#values[@]} values, expected $4"
}

mbt_version() {
    IFS=. read -r major minor patch <<<"$version"
    local unit
    for unit in $GATEWAY 255; do
        mbt_read "$unit" 4 0 2 || return 1
        ((values[0] == (major << 8 | minor) && values[1] == patch)) ||
            fail "unit $unit VERSION ${values[*]}, expected $((major << 8 | minor)) $patch" || return 1
    done
}

mbt_watchdog() {
    mbt_write 255 6 60000 && mbt_read 255 4 6 1 || return 1
    ((values[0] == 60000)) || fail "WATCHDOG reads ${values[0]} after writing 60000" || return 1
    mbt_write 255 6 0
}

mbt_unserved() {
    mbt -a 99 -t 4 -r 0 -c 1
    if ((mb_rc == 0)) || ! grep -qi "gateway path unavailable" <<<"$mb_out"; then
        fail "unit 99: '$(mb_error)', expected exception 0A (gateway path unavailable)"
    fi
}

mbt_tcp_settings() {
    # TCPMAX TCPIDLE TCPCONN: the defaults, and this one connection open.
    mbt_read 255 4 0x0605 3 || return 1
    [[ ${values[*]} == "4 60 1" ]] || fail "TCPMAX TCPIDLE TCPCONN = ${values[*]}, expected 4 60 1"
}

mbt_axes() {
    local deadline=$((SECONDS + 20))
    while :; do
        mbt -a 1,2,3 -t 4 -r 0x9F02
        [[ $(sed -n 's/^\[[0-9]*\]:[[:space:]]*//p' <<<"$mb_out" | paste -sd, -) == 1,1,1 ]] && break
        ((SECONDS < deadline)) || fail "LINK of units 1-3 not all 1 over TCP: $mb_out" || return 1
        sleep 0.1
    done
    mbt_read 1 4 0x9005 1 || return 1
    ((values[0] & PWR)) || fail "unit 1 DSS1 ${values[0]}: PWR off"
}

tcp_suite() {
    start_tcp_gateway
    failed_before=$failures
    run_client_tcp() {
        local out="$target/interop/libmodbus-tcp-$kind.out" status=0 failed groups=(tcp)
        [[ $kind == host ]] && groups+=(tcp-axes)
        timeout --kill-after=10 300 "$client" "tcp:127.0.0.1:$tcp_port" "$version" "$AXES" "${groups[@]}" |
            sed -u "s#^\(ok\|FAIL\|skip\) #\1 $kind/#" | tee "$out" || status=$?
        failed=$(grep -c '^FAIL' "$out" || true)
        ((failed > 0 || status == 0)) || failed=1
        failures=$((failures + failed))
    }
    run_client_tcp
    scenario mbpoll-tcp-version mbt_version
    scenario mbpoll-tcp-watchdog mbt_watchdog
    scenario mbpoll-tcp-exception-0a mbt_unserved
    scenario mbpoll-tcp-settings mbt_tcp_settings
    if [[ $kind == host ]]; then
        scenario mbpoll-tcp-axes mbt_axes
    else
        skip mbpoll-tcp-axes "the network firmware in QEMU has no RS485 bus (its axes: rc-gateway-host)"
    fi
    ((failures == failed_before)) || tail -n 30 "$gateway_log"
    stop_tcp_gateway
}

if [[ " ${targets[*]} " == *" firmware "* ]]; then
    scripts/qemu-install.sh
    net_elf=$(scripts/emu-net.sh build)
    elf=$(scripts/emu-build.sh)
    cargo build --locked --quiet -p rc-tools --bin rc-sim
    python=$(scripts/py-env.sh)
fi
for kind in "${targets[@]}"; do
    libmodbus_suite
    mbpoll_suite
    tcp_suite
done

if ((failures)); then
    echo "interop: $failures failed"
    exit 1
fi
echo "interop: all passed (libmodbus, mbpoll; RTU and TCP; ${targets[*]})"
