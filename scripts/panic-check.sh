#!/usr/bin/env bash
# No reachable panic in the project's crates on the boards: disassembles each board firmware (the
# `firmware` profile's ELFs, pab-fw-g474, pab-fw-f446 and pab-fw-an386, and the NUCLEO-G474RE's
# builds that take updates and that run CAN FD; built here if needed) and
# fails when a panic entry point is called or branched to from code of pab_core, pab_app,
# pab_storage or pab_slcan.
#   scripts/panic-check.sh            # build the firmwares with their panic locations, in
#                                     # target/panic-check (cargo skips them when up to date), check
#   scripts/panic-check.sh ELF...     # check these ELFs
#
# How call sites are attributed (scripts/panic_check.py does it, and its header has the details):
# - Panic entry points: the functions whose name matches a pattern (core::panicking::*,
#   core::option::unwrap_failed / expect_failed, core::result::unwrap_failed,
#   core::slice::*_fail, core::str::*slice_error_fail, core::cell::panic_already_borrowed, the
#   panic handlers: rust_begin_unwind, _defmt_panic, __defmt_default_panic, panic_probe::*),
#   plus every function of core/alloc that branches to one and has no return instruction.
# - Call sites: every bl/blx/b/b<cond>/cbz/cbnz (llvm-objdump) whose target is an entry point.
# - Owner: fat LTO inlines our crates into others' functions (everything the node does ends up
#   in embassy's TaskStorage::poll), so symbol names say little. Each site's inline chain comes
#   from the ELF's debug info (arm-none-eabi-addr2line -i; the firmware profile keeps line tables
#   and inlining records, which are not flashed); the owner is the innermost frame outside the
#   Rust standard library: the crate whose code did `x[i]`, `copy_from_slice`, `%`, `unwrap`.
#   A site owned by a checked crate fails the check, printed with its whole chain, whatever
#   the entry point, `panic_const_async_fn_resumed` included: rustc's coroutine transform gives
#   every async fn that can return a "resumed after completion" state that panics; the awaiting
#   code never polls a finished future, but LLVM cannot prove it across suspension points, so
#   the branch stays. The checked crates therefore have no async fn that can return: pab_storage
#   is blocking (flash program and erase stall the CPU on the G474 anyway), and pab_app's only
#   async fns are the node loop, `-> !` (under panic = "abort" the "resumed after panicking"
#   state does not exist either).
# - Not failures, printed one per line: sites owned by the board crates (--report: boot-time
#   unwraps, RefCells in interrupt handlers, the async-fn guards of their bus drivers) and sites
#   owned by libraries (embassy, defmt, critical-section), even when inlined into our code.
# Needs llvm-objdump and llvm-nm (rustup's llvm-tools) and arm-none-eabi-addr2line (Debian's
# binutils-arm-none-eabi, installed with apt-get if missing), and python3.
set -euo pipefail
cd "$(dirname "$0")/.."

bin="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin"
if [ ! -x "$bin/llvm-objdump" ]; then
    rustup component add llvm-tools
fi
scripts/need.sh python3 arm-none-eabi-addr2line=binutils-arm-none-eabi

if [ $# -eq 0 ]; then
    # The firmware built with its panic locations (PAB_PANIC_LOCATION=1, the boards' build.rs),
    # in a target directory of its own so that the flashed build (without them) is not rebuilt.
    # Without locations, every call of one panic entry point passes the same arguments, and
    # LLVM merges the calls of several sites into one block whose debug information names one of
    # them or none: a site of a board crate then reads as the node loop's, and a site of ours
    # could read as a library's. With them, each site keeps its own call; the panic paths are
    # otherwise the same code.
    target="${CARGO_TARGET_DIR:-target}/panic-check"
    export PAB_PANIC_LOCATION=1
    # The NUCLEO-G474RE that takes updates over the bus (identity and the update's code, which
    # the full build has not), kept under its own name; then the full build in its place.
    CARGO_TARGET_DIR="$target" cargo build -q --locked -p pab-fw-g474 --profile firmware \
        --target thumbv7em-none-eabihf --no-default-features --features ble,dynamics,filters,update
    cp "$target/thumbv7em-none-eabihf/firmware/pab-fw-g474" "$target/pab-fw-g474-update"
    # The NUCLEO-G474RE on CAN FD (its FD frame path, and the node's with 64-byte frames).
    CARGO_TARGET_DIR="$target" cargo build -q --locked -p pab-fw-g474 --profile firmware \
        --target thumbv7em-none-eabihf --no-default-features --features ble,dynamics,filters,fd
    cp "$target/thumbv7em-none-eabihf/firmware/pab-fw-g474" "$target/pab-fw-g474-fd"
    CARGO_TARGET_DIR="$target" cargo build -q --locked -p pab-fw-g474 --profile firmware \
        --target thumbv7em-none-eabihf
    # One board a command: their features would unify in one build.
    CARGO_TARGET_DIR="$target" cargo build -q --locked -p pab-fw-f446 --profile firmware \
        --target thumbv7em-none-eabihf
    CARGO_TARGET_DIR="$target" cargo build -q --locked -p pab-fw-an386 --profile firmware \
        --target thumbv7em-none-eabihf --bin pab-fw-an386
    set -- "$target/thumbv7em-none-eabihf/firmware/pab-fw-g474" \
        "$target/thumbv7em-none-eabihf/firmware/pab-fw-f446" \
        "$target/thumbv7em-none-eabihf/firmware/pab-fw-an386" "$target/pab-fw-g474-update" \
        "$target/pab-fw-g474-fd"
fi

exec python3 scripts/panic_check.py --repo . \
    --objdump "$bin/llvm-objdump" --nm "$bin/llvm-nm" --addr2line arm-none-eabi-addr2line \
    --crate pab_core=core --crate pab_app=firmware/app --crate pab_storage=firmware/storage \
    --crate pab_slcan=firmware/slcan \
    --report pab-fw-g474=firmware/boards/nucleo-g474re --report pab-fw-f446=firmware/boards/nucleo-f446re \
    --report pab-fw-an386=firmware/boards/mps2-an386 \
    "$@"
