#!/usr/bin/env bash
# The cross-runner test with the board in it: the same frames through the simulator, the Linux
# node's application and the firmware on the emulated Cortex-M4 (QEMU mps2-an386) must give
# byte-identical records of every verdict (host-tools/tests/cross_runner.rs).
#   scripts/cross-runner.sh                  # every example network and the committed HIL log
#   scripts/cross-runner.sh CAPTURE.log      # ... and this capture, with examples/take-and-return.toml
# Builds pab-an386-replay (the `firmware` profile, thumbv7em-none-eabihf). Needs qemu-system-arm: installed with
# apt-get if missing and root, else the script fails saying so. Never skips.
set -euo pipefail
cd "$(dirname "$0")/.."

if [ $# -gt 1 ]; then
    echo "usage: scripts/cross-runner.sh [CAPTURE.log]" >&2
    exit 2
fi
if [ $# -eq 1 ]; then
    if [ ! -r "$1" ]; then
        echo "cross-runner: cannot read the capture $1" >&2
        exit 2
    fi
    export PAB_REPLAY_CAPTURE
    PAB_REPLAY_CAPTURE=$(realpath "$1")
fi

scripts/need.sh qemu-system-arm

cargo build --profile firmware --locked -p pab-fw-an386 --target thumbv7em-none-eabihf \
    --bin pab-an386-replay
target="${CARGO_TARGET_DIR:-target}"
export PAB_AN386_REPLAY
PAB_AN386_REPLAY=$(realpath "$target/thumbv7em-none-eabihf/firmware/pab-an386-replay")
started=$(date +%s)
# The workspace's integration binaries (only pabctl's has the test): built with the workspace's
# features, as `cargo test` builds them; `-p pabctl` alone resolves other features and rebuilds
# some thirty crates first.
cargo test --locked --test integration cross_runner:: -- --ignored --nocapture
echo "cross-runner: simulator, node application and board agree ($(( $(date +%s) - started )) s)"
