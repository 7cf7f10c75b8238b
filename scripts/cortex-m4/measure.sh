# Sourced by the measurement scripts of programs outside the firmware (dynamics-cost.sh,
# schema-cost.sh): builds one such crate for the emulated board, runs it under QEMU with the
# instruction-counting plugin between its markers (pab_cost_begin / pab_cost_end), and leaves the
# counts in a log. The method, and its checks, are scripts/cortex-m4-cost.sh's.
#
#   measure CRATE_DIR BINARY LOG_NAME     sets $elf (the program) and $log (the counts), and
#                                         $llvm_bin (rustup's llvm-tools, for llvm-nm)
#
# Needs qemu-system-arm, gcc, python3 and llvm-nm (rustup's llvm-tools); the caller runs from
# the repository's root.

measure() {
    local crate="$1" binary="$2" name="$3"
    scripts/need.sh qemu-system-arm gcc python3
    llvm_bin="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin"
    if [ ! -x "$llvm_bin/llvm-nm" ]; then
        rustup component add llvm-tools
    fi
    local target="${CARGO_TARGET_DIR:-$PWD/target}"
    local work="$target/cortex-m4"
    mkdir -p "$work"
    local plugin="$work/insn-count.so" source=scripts/cortex-m4/insn-count.c
    if [ ! -f "$plugin" ] || [ "$source" -nt "$plugin" ]; then
        gcc -shared -fPIC -O2 -Wall -Wextra -Werror -fvisibility=hidden -o "$plugin" "$source"
    fi
    (cd "$crate" &&
        CARGO_TARGET_DIR="$target" cargo build -q --release --target thumbv7em-none-eabihf --locked)
    elf="$target/thumbv7em-none-eabihf/release/$binary"
    local begin end
    begin=$("$llvm_bin/llvm-nm" "$elf" | awk '$3 == "pab_cost_begin" { print "0x" $1 }')
    end=$("$llvm_bin/llvm-nm" "$elf" | awk '$3 == "pab_cost_end" { print "0x" $1 }')
    if [ -z "$begin" ] || [ -z "$end" ] || [ "$begin" = "$end" ]; then
        echo "$name: markers not found (or merged) in $elf" >&2
        exit 1
    fi
    log="$work/$name.log"
    if ! qemu-system-arm -M mps2-an386 -nographic -monitor none \
        -semihosting-config enable=on,target=native -icount shift=0 \
        -plugin "$plugin,begin=$begin,end=$end" -kernel "$elf" 2> "$log" > /dev/null; then
        tail -5 "$log" >&2
        echo "$name: the measurement program failed (log: $log)" >&2
        exit 1
    fi
}
