#!/usr/bin/env bash
# A firmware update's transfer time (issue 37): `rcgw update` of a full-size signed image (the
# board's whole ACTIVE partition) into `rc-gateway-host --dfu` (embassy-boot's updater on a
# file-backed flash of the board's layout), over Modbus TCP on loopback and over Modbus RTU on a
# pseudo-terminal (no wire time), for the L475 and the F429; measured wall time, then the
# transfer time at 115.2 kbit/s RTU computed from the frames rcgw sends (a chunk's request and
# reply on the wire and the two silent intervals between them), which no pseudo-terminal shows.
# A PC's figures, not a board's: the board's flash steps (the L475's page erase, 25 ms at most
# each; the F429's sector erase, 1-2 s each) come on top; docs/bring-up.md rows 18 and E12 time
# them on a board. One line `BENCH_UPDATE {...}` at the end.
#
#   scripts/update-bench.sh
#   UPDATE_BENCH_BOARDS=l475 scripts/update-bench.sh    # one board
set -euo pipefail
cd "$(dirname "$0")/.."
rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
cargo build --release --locked --quiet -p rc-tools --bin rcgw --bin rc-gateway-host
bin="${CARGO_TARGET_DIR:-target}/release"
python=$(scripts/py-env.sh)
exec "$python" - "$bin" <<'EOF'
import json, os, subprocess, sys, tempfile, time

bin_dir = sys.argv[1]
rcgw = os.path.join(bin_dir, "rcgw")
host = os.path.join(bin_dir, "rc-gateway-host")

# The boards' ACTIVE partitions (rc_boot::layout: the largest image), and the chunk rcgw sends
# (protocol::plc::update::MAX_CHUNK).
BOARDS = {"l475": 480 * 1024, "f429": 768 * 1024}
IDS = {"l475": "0x0475", "f429": "0x0429"}
BOARDS = {b: BOARDS[b] for b in os.environ.get("UPDATE_BENCH_BOARDS", "l475 f429").split()}
TRAILER = 96
MAX_CHUNK = 232


def rtu_seconds(size, baud=115200):
    """The image's chunks on an RTU line at `baud`: each FC16 request (unit, function, address,
    count, byte count, the 4 header registers and the bytes, CRC) and its 8-byte reply, 11 bits
    a character, plus the two t3.5 silences (1.75 ms each above 19.2 kbit/s, Modbus over serial
    line V1.02 2.5.1.1). The gateway's own turn-around and rcgw's status reads are not counted."""
    seconds = 0.0
    left = size
    while left > 0:
        n = min(MAX_CHUNK, left)
        request = 1 + 1 + 2 + 2 + 1 + 2 * (4 + (n + 1) // 2) + 2
        seconds += (request + 8) * 11 / baud + 2 * 0.00175
        left -= n
    return seconds


def start(flash, board):
    gw = subprocess.Popen(
        [host, "--plc-pty", "--modbus-tcp", "127.0.0.1:0", "--sim", "2", "--control",
         "--watchdog-ms", "0", "--dfu", flash, "--board-id", IDS[board]],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    pty = tcp = None
    while pty is None or tcp is None:
        line = gw.stdout.readline()
        if not line:
            raise SystemExit(f"update-bench: rc-gateway-host --board-id {board} ended")
        if line.startswith("PLC "):
            pty = line[4:].strip()
        elif line.startswith("TCP "):
            tcp = line[4:].strip()
    return gw, pty, tcp


rows = []
with tempfile.TemporaryDirectory() as tmp:
    for board, active in BOARDS.items():
        app = os.path.join(tmp, f"{board}.bin")
        image = os.path.join(tmp, f"{board}.img")
        with open(app, "wb") as f:
            f.write(os.urandom(active - TRAILER))
        subprocess.run([rcgw, "sign", app, "--test-key", "--board", board, "--version", "9.9.9",
                        "--out", image], check=True, capture_output=True)
        size = os.path.getsize(image)
        for link in ("tcp", "rtu"):
            flash = os.path.join(tmp, f"{board}-{link}.flash")
            gw, pty, tcp = start(flash, board)
            try:
                where = ["--tcp", tcp] if link == "tcp" else ["--rtu", pty]
                began = time.monotonic()
                run = subprocess.run([rcgw, *where, "update", image], capture_output=True,
                                     text=True, timeout=900)
                took = time.monotonic() - began
                if run.returncode != 0:
                    raise SystemExit(f"update-bench: {board} over {link}: rcgw update failed:\n"
                                     f"{run.stdout}\n{run.stderr}")
            finally:
                gw.stdin.close()
                gw.wait(timeout=30)
            rows.append({"board": board, "link": link, "bytes": size,
                         "seconds": round(took, 2), "kb_per_s": round(size / took / 1000, 1)})
        rows.append({"board": board, "link": "rtu-115200-computed", "bytes": size,
                     "seconds": round(rtu_seconds(size), 1),
                     "kb_per_s": round(size / rtu_seconds(size) / 1000, 2)})

print(f"{'board':6} {'link':22} {'bytes':>8} {'seconds':>8} {'KB/s':>7}")
for r in rows:
    print(f"{r['board']:6} {r['link']:22} {r['bytes']:>8} {r['seconds']:>8} {r['kb_per_s']:>7}")
print("BENCH_UPDATE " + json.dumps({"update_transfer": rows}))
EOF
