#!/usr/bin/env bash
# Cortex-M4 instructions per tick of the schema server (core/src/schema/), counted exactly on
# the emulated board (QEMU mps2-an386) with the plugin and the marker method of
# scripts/cortex-m4-cost.sh (read it for the method and its checks). The program is its own
# crate, scripts/cortex-m4/schema-cost/, outside the firmware: the schema server is not in the
# firmware yet, and measuring it leaves the firmware images as they are.
#
#   scripts/cortex-m4/schema-cost.sh        per case and class: median and largest instructions
#                                           per tick, and the share of a 170 MHz Cortex-M4 at
#                                           1 kHz; the tick's code size
#
# Needs qemu-system-arm, gcc, python3 and llvm-nm (rustup's llvm-tools): see measure.sh.
set -euo pipefail
cd "$(dirname "$0")/../.."

. scripts/cortex-m4/measure.sh
measure scripts/cortex-m4/schema-cost pab-schema-cost schema-cost

# The code of a tick: the measured function and what it calls (LTO inlines most of
# `Server::tick`; what stays out of line is listed by `--print-size`), the markers aside.
tick_bytes=$("$llvm_bin/llvm-nm" --print-size --size-sort -C "$elf" |
    python3 -c 'import sys; print(hex(sum(int(l.split()[1], 16) for l in sys.stdin
        if len(l.split()) >= 4 and ("pab_core::schema" in l or "measured_tick" in l))))')

python3 - "$log" "$tick_bytes" <<'PY'
import re, statistics, sys
count, cases, empty = None, {}, None
for line in open(sys.argv[1]):
    m = re.match(r"insn-count region \d+: (\d+)", line)
    if m:
        count = int(m.group(1))
        continue
    m = re.match(r"pab-cost (\S+) (\S+)", line)
    if m:
        if count is None:
            sys.exit(f"schema-cost: '{line.strip()}' without a count before it")
        if m.group(1) == "calibrate":
            empty = count
        else:
            cases.setdefault((m.group(1), m.group(2)), []).append(count)
        count = None
if empty is None or not cases:
    sys.exit("schema-cost: nothing measured")
print(f"Instructions per Server::tick on a Cortex-M4 (markers' {empty} subtracted); "
      f"tick code {int(sys.argv[2], 16)} bytes")
print(f"{'case':<14} {'class':<7} {'ticks':>6} {'median':>8} {'largest':>8} {'1 kHz on 170 MHz':>17}")
for (case, cls), counts in cases.items():
    counts = [c - empty for c in counts]
    median, largest = statistics.median(counts), max(counts)
    share = largest * 1000 / 170e6 * 100
    print(f"{case:<14} {cls:<7} {len(counts):>6} {median:>8.0f} {largest:>8} {share:>16.2f}%")
PY
