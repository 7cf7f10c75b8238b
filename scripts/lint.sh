#!/usr/bin/env bash
# The lints and the documentation build, warnings denied:
#   scripts/lint.sh
# clippy on the host crates (every target: libraries, binaries, tests, benches, examples) and on
# the boards' crates for thumbv7em-none-eabihf (the core with and without defmt, the storage, the
# node application with and without embassy, the three firmwares in release as they are flashed,
# the emulated board's bootloader and the board behind it, the NUCLEO boards' bootloaders and the
# boards behind them, the two builds that take updates over the bus, the SLCAN codec, the
# builtins and the example firmware on bxCAN); then rustdoc on the host crates, where a broken or ambiguous
# intra-doc link fails.
# ./test.sh runs it in the background while the other steps run; alone it takes about two
# minutes from an empty target directory on two cores.
set -euo pipefail
cd "$(dirname "$0")/.."

# Host crates: the workspace's default members (every crate but the boards; `--workspace` would
# pull the Cortex-M firmware into a host build).
cargo clippy --all-targets --locked -- -D warnings
cargo clippy -p pab-core --target thumbv7em-none-eabihf --locked -- -D warnings
cargo clippy -p pab-core --features defmt --target thumbv7em-none-eabihf --locked -- -D warnings
cargo clippy -p pab-storage --target thumbv7em-none-eabihf --locked -- -D warnings
cargo clippy -p pab-app --target thumbv7em-none-eabihf --locked -- -D warnings
# The node application without embassy (PollLoop, EmbeddedCan) and with its test bus.
cargo clippy -p pab-app --no-default-features --features test-bus --target thumbv7em-none-eabihf --locked -- -D warnings
cargo clippy -p pab-fw-g474 --target thumbv7em-none-eabihf --release --locked -- -D warnings
# The minimal node: every mechanism left out (docs/footprint.md).
cargo clippy -p pab-fw-g474 --no-default-features --target thumbv7em-none-eabihf --release --locked -- -D warnings
cargo clippy -p pab-fw-f446 --target thumbv7em-none-eabihf --release --locked -- -D warnings
cargo clippy -p pab-slcan --target thumbv7em-none-eabihf --locked -- -D warnings
cargo clippy -p pab-builtins --target thumbv7em-none-eabihf --locked -- -D warnings
# With the cost binary's firmware-update case (`update-cost`), as scripts/cortex-m4-cost.sh builds it.
cargo clippy -p pab-fw-an386 --features update-cost --target thumbv7em-none-eabihf --release --locked -- -D warnings
# The emulated board's bootloader, and the board behind it (feature `boot`: src/boot.rs and the
# bootloader's test application).
cargo clippy -p pab-boot-an386 --target thumbv7em-none-eabihf --release --locked -- -D warnings
# Its test build (`reset-test`: a reset in place of one partition operation), as
# scripts/boot-reset-test.sh builds it.
cargo clippy -p pab-boot-an386 --features reset-test --target thumbv7em-none-eabihf --release --locked -- -D warnings
cargo clippy -p pab-fw-an386 --features boot --target thumbv7em-none-eabihf --release --locked -- -D warnings
# The node that takes updates over the bus (`update`), as scripts/boot-test.sh builds it.
cargo clippy -p pab-fw-an386 --no-default-features --features ble,dynamics,filters,update --target thumbv7em-none-eabihf --release --locked -- -D warnings
# The NUCLEO boards' bootloaders (with pab-boot-common, the flow they share), and the boards
# behind them (feature `boot`: linked at the active partition; the F446's without store and boot
# counter).
cargo clippy -p pab-boot-g474 --target thumbv7em-none-eabihf --release --locked -- -D warnings
cargo clippy -p pab-boot-f446 --target thumbv7em-none-eabihf --release --locked -- -D warnings
cargo clippy -p pab-fw-g474 --features boot --target thumbv7em-none-eabihf --release --locked -- -D warnings
# The NUCLEO-G474RE that takes updates over the bus (`update`: the emulated board's set), as
# scripts/firmware-size.sh builds it.
cargo clippy -p pab-fw-g474 --no-default-features --features ble,dynamics,filters,update --target thumbv7em-none-eabihf --release --locked -- -D warnings
# The NUCLEO-G474RE on CAN FD (`fd`), as scripts/firmware-size.sh builds it.
cargo clippy -p pab-fw-g474 --no-default-features --features ble,dynamics,filters,fd --target thumbv7em-none-eabihf --release --locked -- -D warnings
cargo clippy -p pab-fw-f446 --features boot --target thumbv7em-none-eabihf --release --locked -- -D warnings
cargo clippy -p pab-own-driver --features board --target thumbv7em-none-eabihf --release --locked -- -D warnings

# The host crates' documentation: a broken or ambiguous intra-doc link fails.
RUSTDOCFLAGS="-D warnings" cargo doc --no-deps --locked --quiet
echo "lint: clippy and rustdoc clean"
