#!/usr/bin/env bash
# Installs flip-link, the linker wrapper `.cargo/config.toml` names for both firmware targets (it
# puts the stack below .data/.bss, so that an overflow faults at the bottom of RAM instead of
# overwriting the statics), when it is not on the PATH. Every script that links the firmware runs
# this first; idempotent, and instant when flip-link is there. `cargo clippy` and `cargo check`
# do not link and do not need it.
#
# Pinned: 0.1.12 builds with the pinned toolchain (rust-toolchain.toml, 1.95.0). `--locked`: the
# versions of its dependencies that its release was tested with.
set -euo pipefail
cd "$(dirname "$0")/.."

FLIP_LINK_VERSION=0.1.12

command -v flip-link >/dev/null 2>&1 && exit 0
echo "flip-link-install: installing flip-link $FLIP_LINK_VERSION (cargo install)" >&2
cargo install flip-link --locked --version "$FLIP_LINK_VERSION" --quiet >&2
if ! command -v flip-link >/dev/null 2>&1; then
    echo "flip-link-install: installed, but not on the PATH (add cargo's bin directory, ~/.cargo/bin)" >&2
    exit 1
fi
