#!/usr/bin/env bash
# A reset at every step of the emulated board's bootloader (firmware/boot/mps2-an386): the
# update's verdict and mark, every page copy, progress record and erase of embassy-boot's swap and
# of its revert, each replaced in turn by a system reset in its own QEMU run; each run must end on
# the old firmware or the new one, as the step implies, with the bootloader's expected messages
# (scripts/boot_reset_test.py says how).
#   scripts/boot-reset-test.sh
# Builds pab-boot-an386 with its feature `reset-test` (a test build: pab_boot_an386::reset_test)
# and keeps its ELF as $target/boot-reset-test/pab-boot-an386-reset-test, then builds it again
# without the feature (the path other scripts take it from keeps the release build); builds the
# test application pab-an386-boottest (feature `boot`) and pabctl (signing). Needs
# qemu-system-arm (installed with apt-get if missing) and python3.
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/need.sh qemu-system-arm python3
target="${CARGO_TARGET_DIR:-target}"
out="$target/thumbv7em-none-eabihf/firmware"
tools="$(rustc --print sysroot)/lib/rustlib/x86_64-unknown-linux-gnu/bin"
mkdir -p "$target/boot-reset-test"
cargo build -q --locked --profile firmware -p pab-boot-an386 --target thumbv7em-none-eabihf \
    --features reset-test
cp "$out/pab-boot-an386" "$target/boot-reset-test/pab-boot-an386-reset-test"
cargo build -q --locked --profile firmware -p pab-boot-an386 --target thumbv7em-none-eabihf
cargo build -q --locked --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \
    --features boot --bin pab-an386-boottest
cargo build -q --locked -p pabctl
"$tools/llvm-objcopy" -O binary "$out/pab-an386-boottest" "$target/boot-reset-test/boottest-v1.bin"
python3 scripts/boot_reset_test.py "$target/boot-reset-test/pab-boot-an386-reset-test" \
    "$target/boot-reset-test/boottest-v1.bin" "$target/debug/pabctl"
