#!/usr/bin/env bash
# Cortex-M4 instructions per frame, counted exactly on the emulated board (QEMU mps2-an386):
#
#   scripts/cortex-m4-cost.sh                 the table: instructions per frame, per case
#   scripts/cortex-m4-cost.sh --check         the same, failing if a goal of issue 10 is exceeded
#                                             or a goal not met gets worse (exact counts: a
#                                             deterministic check, not a timing)
#   scripts/cortex-m4-cost.sh --profile CASE[/CLASS][@MIN]
#                                             where that case's instructions go (its frames of at
#                                             least MIN instructions), per function symbol and
#                                             per source line (inlined code included)
#
# How: the firmware binary pab-an386-cost (firmware/boards/mps2-an386/src/bin/cost/) runs each
# case between two marker functions; a QEMU TCG plugin built here from
# scripts/cortex-m4/insn-count.c counts every guest instruction executed between them; the
# count of an empty region (the marker calls) is subtracted. The method is checked on every run
# (scripts/cortex-m4/report.py): loops of known length must be counted exactly (2N + 1
# instructions for N iterations), and under `-icount shift=0` (one instruction per virtual ns)
# SysTick on the 25 MHz CPU clock must agree (one tick = 40 instructions).
#
# Needs qemu-system-arm, gcc and python3 (installed with apt-get if missing and root),
# llvm-nm from rustup's llvm-tools component (installed here if missing), and for --profile
# binutils' addr2line (it follows the inlining chains in the debug information).
# Takes a few seconds once the firmware is built.
set -euo pipefail
cd "$(dirname "$0")/.."

mode=table
profile_case=
case "${1:-}" in
    "") ;;
    --check) mode=check ;;
    --profile)
        mode=profile
        profile_case="${2:?--profile needs CASE or CASE/CLASS, e.g. walk-16 or tr-arm/fed}"
        ;;
    -h | --help)
        sed -n '2,24p' "$0" | sed 's/^# \{0,1\}//'
        exit 0
        ;;
    *)
        echo "cortex-m4-cost: unknown argument '$1' (see --help)" >&2
        exit 2
        ;;
esac

# The plugin, the markers and the run under the plugin: shared with the other counts.
. scripts/cortex-m4/measure.sh
cortex_m4_setup

# The boards' profile (root Cargo.toml): what is counted is what a board runs.
# `update-cost`: the firmware-update case (a signed image's check), which the node's own
# firmware does not link.
cargo build -q --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \
    --bin pab-an386-cost --features update-cost --locked
elf="${CARGO_TARGET_DIR:-target}/thumbv7em-none-eabihf/firmware/pab-an386-cost"

cortex_m4_markers "$elf" cortex-m4-cost

# Runs the program once under the plugin (extra plugin options in $1) into $2.
run() {
    cortex_m4_run "$elf" "$2" cortex-m4-cost "$1"
}

log="$work/run.log"
run "" "$log"
report=(python3 scripts/cortex-m4/report.py "$log")
case "$mode" in
    table) "${report[@]}" ;;
    check) "${report[@]}" --check ;;
    profile)
        "${report[@]}" --regions "$profile_case" > "$work/regions.txt"
        histogram="$work/profile.txt"
        run ",profile=$histogram,only=$work/regions.txt" "$work/profile.log"
        "${report[@]}" --profile "$profile_case" "$histogram" "$elf"
        ;;
esac
