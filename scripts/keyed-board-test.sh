#!/usr/bin/env bash
# A keyed emulated board, end to end (host-tools/tests/keyed_board.rs): pab-fw-an386 in QEMU's
# mps2-an386 with a key page made by `pabctl keygen` and `pabctl keypage` (planted by QEMU's
# loader at 0x0004_E000), over its SLCAN serial line: keyed in its heartbeat, plain commands and
# pushes refused, pabctl's keyed push and a tagged DiagnosticControl taken, and after a system
# reset the next boot count as the challenges' salt.
#   scripts/keyed-board-test.sh
# Builds pab-fw-an386 (the `firmware` profile). Needs qemu-system-arm (installed with apt-get if
# missing). Never skips.
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/need.sh qemu-system-arm
cargo build -q --locked --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \
    --bin pab-fw-an386
target="${CARGO_TARGET_DIR:-target}"
export PAB_AN386_ELF
PAB_AN386_ELF=$(realpath "$target/thumbv7em-none-eabihf/firmware/pab-fw-an386")
# The workspace's integration binaries (only pabctl's has the test): built with the workspace's
# features, as `cargo test` builds them; `-p pabctl` alone resolves other features and rebuilds
# some thirty crates first.
cargo test --locked --test integration keyed_board:: -- --ignored --nocapture
