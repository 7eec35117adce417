#!/usr/bin/env bash
# The settings store's long power-cut campaign (store/tests/harsh.rs): CUTS random power cuts on
# each board's flash geometry (F103, L475 with ECC, F429; three threads), from SEED. It prints,
# per board, the saves, the cuts (in a program unit, in an erase), the starts and the
# violations, and fails on any violation. CI runs the same test with 2 000 cuts per board.
#
#   scripts/store-campaign.sh                 # 1 000 000 cuts per board (about 20 minutes on 2 cores)
#   scripts/store-campaign.sh CUTS [SEED]
set -euo pipefail
cd "$(dirname "$0")/.."

# The dev profile: the store is built with opt-level 3 there (Cargo.toml), without the release
# profile's LTO and size optimisation.
STORE_CAMPAIGN_CUTS=${1:-1000000} STORE_CAMPAIGN_SEED=${2:-53} \
    cargo test -p settings-store --test harsh campaign -- --nocapture
