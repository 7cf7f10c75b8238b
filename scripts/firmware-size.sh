#!/usr/bin/env bash
# Flash and static RAM of the board firmware, from its build with the `firmware` profile (the one
# that is flashed; see the root Cargo.toml):
#   scripts/firmware-size.sh            (builds pab-fw-g474, pab-fw-f446 and pab-fw-an386, one
#                                        at a time; cargo skips them when up to date)
# Needs llvm-size from rustup's llvm-tools component (installed here if missing). The firmware
# must stay within 64 KiB of flash (text + data), and its deepest chain of calls must leave 8 KiB
# of its stack (scripts/stack-depth.py says how it is measured).
set -euo pipefail
cd "$(dirname "$0")/.."

target="${CARGO_TARGET_DIR:-target}"
size="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin/llvm-size"
if [ ! -x "$size" ]; then
    rustup component add llvm-tools
fi

# report PACKAGE DESCRIPTION PROGRAM_REGION RAM_TEXT
report() {
    local package="$1" description="$2" region="$3" ram_text="$4"
    local elf="$target/thumbv7em-none-eabihf/firmware/$package"
    cargo build -q -p "$package" --profile firmware --target thumbv7em-none-eabihf --locked
    "$size" "$elf"
    local text data bss
    read -r text data bss < <("$size" "$elf" | awk 'NR == 2 { print $1, $2, $3 }')
    local flash=$(( text + data )) ram=$(( data + bss ))
    awk -v name="$package ($description)" -v flash="$flash" -v ram="$ram" -v region="$region" \
        -v ram_text="$ram_text" 'BEGIN {
        printf "%s: flash %d bytes (%.1f KiB of %s), RAM %d bytes (%.1f KiB of %s)\n",
            name, flash, flash / 1024, region, ram, ram / 1024, ram_text
    }'
    if [ "$flash" -gt 65536 ]; then
        echo "firmware-size: $package takes $flash bytes of flash, more than 64 KiB" >&2
        exit 1
    fi
    # The stack is what the statics leave of the RAM, below them (flip-link).
    python3 scripts/stack-depth.py "$elf"
}

echo "flash = text+data, RAM = data+bss (static)"
report pab-fw-g474 "NUCLEO-G474RE" "the 256 KiB program region (bank 1), 512 KiB chip" \
    "128 KiB; the rest is the stack"
report pab-fw-f446 "NUCLEO-F446RE" "the 128 KiB program region (sector 5), 512 KiB chip" \
    "128 KiB; the rest is the stack"
report pab-fw-an386 "emulated Cortex-M4, QEMU mps2-an386" "the 256 KiB program region" \
    "4 MiB; the rest is the stack"

# The NUCLEO-G474RE with identity and configuration over the bus (feature `identity`), which does
# not fit yet: built and sized to say by how much, not flashed (docs/figures.md). In the same
# target directory (its dependencies' artifacts are shared; only the crates the feature changes are
# built again), its ELF copied aside, then the flashed build's put back where it was.
cargo build -q -p pab-fw-g474 --profile firmware --target thumbv7em-none-eabihf --locked \
    --features identity
mkdir -p "$target/identity"
elf="$target/identity/pab-fw-g474"
cp "$target/thumbv7em-none-eabihf/firmware/pab-fw-g474" "$elf"
cargo build -q -p pab-fw-g474 --profile firmware --target thumbv7em-none-eabihf --locked
read -r text data _ < <("$size" "$elf" | awk 'NR == 2 { print $1, $2, $3 }')
flash=$(( text + data ))
echo "pab-fw-g474 --features identity (not flashed): flash $flash bytes, $(( flash - 65536 )) over 64 KiB"
