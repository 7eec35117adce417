#!/usr/bin/env bash
# Installs qemu-system-arm >= 10 (its `b-l475e-iot01a` machine models the STM32L475VG's USARTs,
# GPIO and EXTI well enough to run the firmware) when it is missing or older. Debian bookworm ships
# 7.2, whose STM32L4 model is unusable; bookworm-backports has 10.x. Idempotent: does nothing when
# a new enough QEMU is on the PATH. Needs root (or sudo) for apt.
set -euo pipefail

MIN_MAJOR=10
SOURCE=/etc/apt/sources.list.d/bookworm-backports.sources

qemu_major() {
    command -v qemu-system-arm >/dev/null 2>&1 || { echo 0; return; }
    # "QEMU emulator version 10.0.2 (Debian 1:10.0.2+ds-1~bpo12+1)"
    qemu-system-arm --version | sed -n 's/^QEMU emulator version \([0-9]*\)\..*/\1/p' | head -n1
}

major=$(qemu_major)
if [[ "${major:-0}" -ge "$MIN_MAJOR" ]]; then
    exit 0
fi

sudo=()
if [[ $(id -u) -ne 0 ]]; then
    command -v sudo >/dev/null 2>&1 || { echo "qemu-install: need root or sudo for apt-get" >&2; exit 1; }
    sudo=(sudo)
fi

. /etc/os-release
if [[ "${VERSION_CODENAME:-}" != bookworm ]]; then
    echo "qemu-install: expected Debian bookworm, found ${PRETTY_NAME:-unknown};" \
         "install qemu-system-arm >= $MIN_MAJOR yourself" >&2
    exit 1
fi

echo "qemu-install: qemu-system-arm ${major:-none} < $MIN_MAJOR; installing from bookworm-backports" >&2
if [[ ! -f "$SOURCE" ]]; then
    "${sudo[@]}" tee "$SOURCE" >/dev/null <<'SOURCES'
Types: deb
URIs: http://deb.debian.org/debian
Suites: bookworm-backports
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
SOURCES
fi
"${sudo[@]}" apt-get update -qq
DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y -qq --no-install-recommends \
    -t bookworm-backports qemu-system-arm >/dev/null

major=$(qemu_major)
if [[ "${major:-0}" -lt "$MIN_MAJOR" ]]; then
    echo "qemu-install: still qemu-system-arm ${major:-none} after the install" >&2
    exit 1
fi
qemu-system-arm --version | head -n1 >&2
