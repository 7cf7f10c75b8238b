# Sourced by every script that counts Cortex-M4 instructions on the emulated board
# (scripts/cortex-m4-cost.sh, dynamics-cost.sh, schema-cost.sh): one build of the QEMU TCG plugin
# (insn-count.c), the markers' addresses, and a run under the plugin. The method, and its checks,
# are scripts/cortex-m4-cost.sh's.
#
#   cortex_m4_setup                      needs and builds what a count needs; sets $llvm_bin
#                                        (rustup's llvm-tools), $work (target/cortex-m4) and
#                                        $plugin (the plugin, rebuilt when its source changed)
#   cortex_m4_markers ELF WHO            sets $begin and $end, the addresses of pab_cost_begin
#                                        and pab_cost_end in ELF (WHO names the caller in errors)
#   cortex_m4_run ELF LOG WHO [OPTIONS]  runs ELF under the plugin between the markers, its
#                                        console and counts into LOG (extra plugin options: ,k=v)
#   measure CRATE_DIR BINARY LOG_NAME    for a program outside the firmware: builds the crate for
#                                        the board, runs it, and sets $elf and $log
#
# Needs qemu-system-arm, gcc, python3 and llvm-nm (rustup's llvm-tools, installed here if
# missing); the caller runs from the repository's root.

cortex_m4_setup() {
    scripts/need.sh qemu-system-arm gcc python3
    llvm_bin="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin"
    if [ ! -x "$llvm_bin/llvm-nm" ]; then
        rustup component add llvm-tools
    fi
    local target="${CARGO_TARGET_DIR:-$PWD/target}"
    work="$target/cortex-m4"
    mkdir -p "$work"
    plugin="$work/insn-count.so"
    local source=scripts/cortex-m4/insn-count.c
    if [ ! -f "$plugin" ] || [ "$source" -nt "$plugin" ]; then
        gcc -shared -fPIC -O2 -Wall -Wextra -Werror -fvisibility=hidden -o "$plugin" "$source"
    fi
}

cortex_m4_markers() {
    local elf="$1" who="$2"
    begin=$("$llvm_bin/llvm-nm" "$elf" | awk '$3 == "pab_cost_begin" { print "0x" $1 }')
    end=$("$llvm_bin/llvm-nm" "$elf" | awk '$3 == "pab_cost_end" { print "0x" $1 }')
    if [ -z "$begin" ] || [ -z "$end" ] || [ "$begin" = "$end" ]; then
        echo "$who: markers not found (or merged) in $elf: begin '$begin', end '$end'" >&2
        exit 1
    fi
}

# QEMU's exit status is the program's (semihosting); its console and the plugin's counts share
# the log, in the order the guest produced them.
cortex_m4_run() {
    local elf="$1" log="$2" who="$3" options="${4:-}"
    if ! qemu-system-arm -M mps2-an386 -nographic -monitor none \
        -semihosting-config enable=on,target=native -icount shift=0 \
        -plugin "$plugin,begin=$begin,end=$end$options" -kernel "$elf" 2> "$log" > /dev/null; then
        tail -5 "$log" >&2
        echo "$who: the measurement program failed (log: $log)" >&2
        exit 1
    fi
}

measure() {
    local crate="$1" binary="$2" name="$3"
    cortex_m4_setup
    local target="${CARGO_TARGET_DIR:-$PWD/target}"
    (cd "$crate" &&
        CARGO_TARGET_DIR="$target" cargo build -q --release --target thumbv7em-none-eabihf --locked)
    elf="$target/thumbv7em-none-eabihf/release/$binary"
    cortex_m4_markers "$elf" "$name"
    log="$work/$name.log"
    cortex_m4_run "$elf" "$log" "$name"
}
