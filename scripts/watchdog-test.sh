#!/usr/bin/env bash
# The emulated board's watchdog and stack guard (a test build with the `hang-test` feature, on
# trigger frames): the node loop hangs, the CMSDK APB watchdog resets the machine, and the node
# boots again with its stored table; the node loop recurses until its stack overflows, which
# runs off the RAM's start (flip-link put the stack below the statics) and faults without
# reaching the static data (scripts/watchdog_test.py says how). Also checks that the production
# firmware has no trigger.
#   scripts/watchdog-test.sh
# Builds pab-fw-an386 with the `hang-test` feature (the `firmware` profile), keeps that ELF as
# target/watchdog-test/pab-fw-an386-hang-test, then rebuilds the production one. Needs
# qemu-system-arm (installed with apt-get if missing) and python3.
set -euo pipefail
cd "$(dirname "$0")/.."

scripts/need.sh qemu-system-arm python3
target="${CARGO_TARGET_DIR:-target}"
elf="$target/thumbv7em-none-eabihf/firmware/pab-fw-an386"
mkdir -p "$target/watchdog-test"
cargo build -q --locked --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \
    --bin pab-fw-an386 --features hang-test
cp "$elf" "$target/watchdog-test/pab-fw-an386-hang-test"
cargo build -q --locked --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \
    --bin pab-fw-an386
if grep -q "hang-test" "$elf"; then
    echo "watchdog-test: the production firmware $elf contains the hang trigger" >&2
    exit 1
fi
if ! grep -q "hang-test" "$target/watchdog-test/pab-fw-an386-hang-test"; then
    echo "watchdog-test: the test build has no hang trigger: the feature did not apply" >&2
    exit 1
fi
python3 scripts/watchdog_test.py "$target/watchdog-test/pab-fw-an386-hang-test" \
    firmware/boards/mps2-an386/tables/take-and-return/arm.pab
