#!/usr/bin/env bash
# Builds the emulator variant of the firmware (feature `emulator`) for QEMU's b-l475e-iot01a
# machine and prints the ELF's path on standard output.
#
# embassy-stm32 0.6.0 needs a few fixes to run under QEMU (emu/embassy-stm32-0.6.0-qemu.patch
# says which and why). They are applied to a copy of the registry source under target/emu/, and
# the build runs in a copy of the workspace (target/emu/ws) whose Cargo.lock may follow the
# `[patch]`: the committed Cargo.lock and the hardware build (`cargo fw --locked`) are never
# touched, even if this script is interrupted. Build artifacts persist in target/emu/target.
#
#   scripts/emu-build.sh            # release build (the default; what the harness runs)
#   PROFILE=dev scripts/emu-build.sh
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
profile=${PROFILE:-release}
target=thumbv7em-none-eabihf
emu=$root/target/emu
patch_file=$root/emu/embassy-stm32-0.6.0-qemu.patch

rustup toolchain install >/dev/null 2>&1 || rustup toolchain install
# The firmware's linker (.cargo/config.toml).
scripts/flip-link-install.sh
lock_before=$(sha256sum Cargo.lock)
cargo fetch --locked --target "$target" >/dev/null

# 1. The patched embassy-stm32, rebuilt from the registry copy whenever the patch changes.
registry_src=$(cargo metadata --locked --format-version 1 --filter-platform "$target" 2>/dev/null |
    python3 -c 'import json,sys
d=json.load(sys.stdin)
print(next(p["manifest_path"] for p in d["packages"] if p["name"]=="embassy-stm32" and p["version"]=="0.6.0"))')
registry_src=$(dirname "$registry_src")
patched=$emu/embassy-stm32-0.6.0
stamp=$(sha256sum "$patch_file" | cut -d' ' -f1)
if [[ ! -f "$patched/.rc-gateway-patch" || $(cat "$patched/.rc-gateway-patch") != "$stamp" ]]; then
    rm -rf "$patched"
    mkdir -p "$emu"
    cp -r "$registry_src" "$patched"
    chmod -R u+w "$patched"
    patch --quiet --forward -p1 -d "$patched" < "$patch_file"
    echo "$stamp" > "$patched/.rc-gateway-patch"
fi

# 2. A copy of the workspace's sources (not target/, not .git): its Cargo.lock is the scratch one.
# Not .cargo/ either: the copy lies inside the repository, so cargo reads the repository's
# .cargo/config.toml already (a second copy would repeat every linker argument).
ws=$emu/ws
rm -rf "$ws"
mkdir -p "$ws"
tar -C "$root" --exclude=./target --exclude=./.git --exclude=./.cargo --exclude='./protocol/fuzz' \
    --exclude='__pycache__' -cf - . | tar -C "$ws" -xf -

# 3. The build. `--config` adds the [patch] to this copy only.
cd "$ws"
CARGO_TARGET_DIR=$emu/target cargo build --quiet --profile "$profile" -p rc-gateway --target "$target" \
    --no-default-features --features emulator \
    --config "patch.crates-io.embassy-stm32.path=\"$patched\""
# The bootloader the application starts behind (the same binary as the board's: it only reads
# the flash when nothing is to be swapped, which QEMU's model allows), beside it in the same
# folder: the harness loads both (tests/pyshared/emu.py).
CARGO_TARGET_DIR=$emu/target cargo build --quiet --profile "$profile" -p rc-bootloader --target "$target" \
    --config "patch.crates-io.embassy-stm32.path=\"$patched\""
cd "$root"
if [[ $(sha256sum Cargo.lock) != "$lock_before" ]]; then
    echo "emu-build: Cargo.lock changed; the emulator build must leave it alone" >&2
    exit 1
fi
dir=$profile
[[ $profile == dev ]] && dir=debug
echo "$emu/target/$target/$dir/rc-gateway"
