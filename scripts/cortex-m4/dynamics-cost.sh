#!/usr/bin/env bash
# Cortex-M4 instructions per step of the competitive dynamics (core/src/dynamics.rs), counted
# exactly on the emulated board (QEMU mps2-an386) with the plugin and the marker method of
# scripts/cortex-m4-cost.sh (read it for the method and its checks). The program is its own
# crate, scripts/cortex-m4/dynamics-cost/, outside the firmware: the dynamics are not in the
# firmware yet, and measuring them leaves the firmware images as they are.
#
#   scripts/cortex-m4/dynamics-cost.sh      per case: median and largest instructions per step,
#                                           and the share of a 170 MHz Cortex-M4 at 1 kHz
#
# Needs qemu-system-arm, gcc, python3 and llvm-nm (rustup's llvm-tools): see measure.sh.
set -euo pipefail
cd "$(dirname "$0")/../.."

. scripts/cortex-m4/measure.sh
measure scripts/cortex-m4/dynamics-cost pab-dynamics-cost dynamics-cost

# The code of the step: the measured function, into which LTO inlines `Dynamics::step`.
step_bytes=$("$llvm_bin/llvm-nm" --print-size --size-sort -C "$elf" |
    awk '/measured_step/ { print $2 }')

python3 - "$log" "$step_bytes" <<'PY'
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
            sys.exit(f"dynamics-cost: '{line.strip()}' without a count before it")
        if m.group(1) == "calibrate":
            empty = count
        else:
            cases.setdefault(m.group(1), []).append(count)
        count = None
    elif line.startswith("pab-gates"):
        _, case, gates = line.split()
        if int(gates, 16) == 0:
            sys.exit(f"dynamics-cost: no gate ever opened in {case}: not a representative run")
if empty is None or not cases:
    sys.exit("dynamics-cost: nothing measured")
print(f"Instructions per Dynamics::step on a Cortex-M4 (markers' {empty} subtracted); "
      f"step code {int(sys.argv[2], 16)} bytes")
print(f"{'case':<10} {'steps':>6} {'median':>8} {'largest':>8} {'1 kHz on 170 MHz':>17}")
for case, counts in cases.items():
    counts = [c - empty for c in counts]
    median, largest = statistics.median(counts), max(counts)
    share = largest * 1000 / 170e6 * 100
    print(f"{case:<10} {len(counts):>6} {median:>8.0f} {largest:>8} {share:>16.2f}%")
PY
