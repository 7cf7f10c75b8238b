#!/usr/bin/env bash
# Flash and static RAM of the board firmware, from its release build:
#   scripts/firmware-size.sh            (builds pab-fw-g474 first if needed)
# Needs llvm-size from rustup's llvm-tools component (installed here if missing).
set -euo pipefail
cd "$(dirname "$0")/.."

target="${CARGO_TARGET_DIR:-target}"
elf="$target/thumbv7em-none-eabihf/release/pab-fw-g474"
if [ ! -f "$elf" ]; then
    cargo build -p pab-fw-g474 --release --target thumbv7em-none-eabihf --locked
fi
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
