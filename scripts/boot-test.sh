#!/usr/bin/env bash
# The emulated board's bootloader (firmware/boot/mps2-an386, on embassy-boot) in real QEMU runs:
# factory install; a signed update checked, swapped in and confirmed; one left unconfirmed (a
# reset, a hang under the watchdog) and reverted; updates signed by another key, for another
# board, changed after signing, or with no update key on the board, refused with the verdict's
# code and never swapped (scripts/boot_test.py says how).
#   scripts/boot-test.sh
# Builds pab-boot-an386, pab-fw-an386's test application pab-an386-boottest and the node firmware
# pab-fw-an386 with the feature `update` (behind the bootloader, linked at the active partition;
# the `firmware` profile;
# then the node firmware again without it, as the other tests take it) and pabctl (signing), prints
# the bootloader's flash size (text + data, llvm-size), and fails if it is over its region
# (32 KiB). Needs qemu-system-arm (installed with apt-get if missing) and python3.
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/need.sh qemu-system-arm python3
target="${CARGO_TARGET_DIR:-target}"
out="$target/thumbv7em-none-eabihf/firmware"
tools="$(rustc --print sysroot)/lib/rustlib/x86_64-unknown-linux-gnu/bin"
cargo build -q --locked --profile firmware -p pab-boot-an386 --target thumbv7em-none-eabihf
cargo build -q --locked --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \
    --features boot --bin pab-an386-boottest
# The node firmware that takes updates over the bus (`update`: behind the bootloader, with
# identity), without the schema server: the full set with identity and the update does not fit
# the active partition yet (docs/firmware-update.md).
cargo build -q --locked --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \
    --no-default-features --features ble,dynamics,filters,update --bin pab-fw-an386
cargo build -q --locked -p pabctl
mkdir -p "$target/boot-test"
"$tools/llvm-objcopy" -O binary "$out/pab-an386-boottest" "$target/boot-test/boottest-v1.bin"
"$tools/llvm-objcopy" -O binary "$out/pab-fw-an386" "$target/boot-test/pab-fw-an386-boot.bin"
# The node firmware at 0x0 again, as the other scripts and the HIL suite take it from $out.
cargo build -q --locked --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \
    --bin pab-fw-an386

# text (vector table, code, read-only data) + data: what the bootloader takes of its 32 KiB.
read -r text data _ < <("$tools/llvm-size" "$out/pab-boot-an386" | tail -n 1)
size=$((text + data))
echo "boot-test: bootloader flash $size bytes (text $text + data $data; goal 24576, region 32768)"
if [ "$size" -gt 32768 ]; then
    echo "boot-test: the bootloader does not fit its 32 KiB region" >&2
    exit 1
fi
python3 scripts/boot_test.py "$out/pab-boot-an386" "$target/boot-test/boottest-v1.bin" \
    "$target/debug/pabctl" "$target/boot-test/pab-fw-an386-boot.bin"
