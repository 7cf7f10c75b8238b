#!/usr/bin/env bash
# Flash and static RAM of the board firmware, from its build with the `firmware` profile (the one
# that is flashed; see the root Cargo.toml):
#   scripts/firmware-size.sh            (builds pab-fw-g474 first; cargo skips it if up to date)
# Needs llvm-size from rustup's llvm-tools component (installed here if missing).
set -euo pipefail
cd "$(dirname "$0")/.."

target="${CARGO_TARGET_DIR:-target}"
elf="$target/thumbv7em-none-eabihf/firmware/pab-fw-g474"
cargo build -q -p pab-fw-g474 --profile firmware --target thumbv7em-none-eabihf --locked
size="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin/llvm-size"
if [ ! -x "$size" ]; then
    rustup component add llvm-tools
fi

"$size" "$elf"
read -r text data bss < <("$size" "$elf" | awk 'NR == 2 { print $1, $2, $3 }')
flash=$(( text + data ))
ram=$(( data + bss ))
echo "flash = text+data, RAM = data+bss (static)"
awk -v flash="$flash" -v ram="$ram" 'BEGIN {
    printf "pab-fw-g474 (NUCLEO-G474RE): flash %d bytes (%.1f KiB of the 464 KiB program region, 512 KiB chip), RAM %d bytes (%.1f KiB of 128 KiB; the rest is the stack)\n",
        flash, flash / 1024, ram, ram / 1024
}'
