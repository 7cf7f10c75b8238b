#!/usr/bin/env python3
"""The deepest stack a board firmware's direct calls can reach, against the stack it has.

    scripts/stack-depth.py ELF [--margin BYTES] [--json]

Reads the ELF's disassembly (llvm-objdump from rustup's llvm-tools) and, per function, the
bytes its prologue takes (`push`, `vpush`, `sub sp`); follows every direct call and tail call
(`bl`, `b` to another function) and prints the deepest chain. The stack is what flip-link (the
boards' linker, `.cargo/config.toml`) leaves below the statics: from the RAM's start
(`_stack_end`) up to the first static (`_stack_start`). Fails (status 1) when the stack is not
below every static (the firmware was linked without flip-link), or when less than `--margin`
bytes (default 8 KiB) would be left below the deepest chain: that is room for the interrupt
handlers, which stack on top of whatever runs, and for the calls through pointers (trait
objects, wakers), which this does not follow.

Why: an overflow runs off the RAM's start and faults (a HardFault, then the watchdog's reset),
which stops the node rather than corrupting it; the margin keeps that from happening in the
first place. The deepest stack is a table being loaded: the new arbiter is built while the old
one runs (docs/nucleo-g474re.md). It is not a proof (no calls through pointers, a frame that
moves `sp` twice counted twice), but it fails when a change makes a frame grow by kilobytes, as
the schema server's set-up once did.
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from pathlib import Path


def tool(name: str) -> str:
    sysroot = subprocess.check_output(["rustc", "--print", "sysroot"], text=True).strip()
    host = re.search(r"^host: (\S+)", subprocess.check_output(["rustc", "-vV"], text=True), re.M)
    return str(Path(sysroot) / "lib" / "rustlib" / host.group(1) / "bin" / name)


FUNCTION = re.compile(r"^([0-9a-f]+) <(.*)>:$")
PUSH = re.compile(r"\tpush(?:\.w)?\s+\{([^}]*)\}")
VPUSH = re.compile(r"\tvpush\s+\{([^}]*)\}")
SUB_SP = re.compile(r"\tsub(?:\.w)?\s+sp, (?:sp, )?#(0x[0-9a-f]+|\d+)")
# A call or a jump; it is a call (or a tail call) when its target starts a function.
BRANCH = re.compile(r"\t(?:bl|b|b\.w)\s+0x([0-9a-f]+)\b")
INDIRECT = re.compile(r"\tblx\s+r\d+")


def parse(elf: str) -> tuple[dict[str, int], dict[str, set[str]], set[str]]:
    """Per function (demangled name): its frame, the functions it calls, and whether it also
    calls through a pointer."""
    text = subprocess.check_output(
        [tool("llvm-objdump"), "-d", "-C", "--no-show-raw-insn", elf], text=True)
    frame: dict[str, int] = {}
    targets: dict[str, set[int]] = {}
    starts: dict[int, str] = {}
    indirect: set[str] = set()
    current = None
    for line in text.splitlines():
        if m := FUNCTION.match(line):
            current = re.sub(r"::h[0-9a-f]{16}$", "", m.group(2))
            for code, char in (("$LT$", "<"), ("$GT$", ">"), ("$C$", ","), ("$u20$", " "),
                               ("$u7b$", "{"), ("$u7d$", "}"), ("$RF$", "&")):
                current = current.replace(code, char)
            # Two functions of one name (generic instances): counted as one, the larger frame.
            starts[int(m.group(1), 16)] = current
            frame.setdefault(current, 0)
            targets.setdefault(current, set())
            own = 0
            continue
        if current is None:
            continue
        if m := PUSH.search(line):
            own += 4 * len(m.group(1).split(","))
        elif m := VPUSH.search(line):
            own += 8 * len(m.group(1).split(","))
        elif m := SUB_SP.search(line):
            own += int(m.group(1), 0)
        elif m := BRANCH.search(line):
            targets[current].add(int(m.group(1), 16))
        elif INDIRECT.search(line):
            indirect.add(current)
        frame[current] = max(frame[current], own)
    calls = {name: {starts[t] for t in ts if t in starts and starts[t] != name}
             for name, ts in targets.items()}
    return frame, calls, indirect


def deepest(frame, calls) -> tuple[int, list[str], set[str]]:
    """The deepest chain, and the functions found calling back into their own chain (a panic
    inside the panic handler's formatting, say): such an edge is not followed, so a real
    recursion would go unbounded here; they are printed."""
    memo: dict[str, tuple[int, list[str]]] = {}
    active: set[str] = set()
    cycles: set[str] = set()

    def depth(name: str) -> tuple[int, list[str]]:
        if name in memo:
            return memo[name]
        active.add(name)
        below: tuple[int, list[str]] = (0, [])
        for callee in calls.get(name, ()):
            if callee in active:
                cycles.add(callee)
                continue
            d = depth(callee)
            if d[0] > below[0]:
                below = d
        active.discard(name)
        memo[name] = (frame[name] + below[0], [name, *below[1]])
        return memo[name]

    sys.setrecursionlimit(100_000)
    total, chain = max((depth(name) for name in frame), key=lambda d: d[0])
    return total, chain, cycles


def symbol(elf: str, name: str) -> int:
    for line in subprocess.check_output([tool("llvm-nm"), elf], text=True).splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[2] == name:
            return int(parts[0], 16)
    raise SystemExit(f"stack-depth: {elf} has no symbol {name} (not a cortex-m-rt firmware?)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("elf")
    parser.add_argument("--margin", type=int, default=8192,
                        help="bytes that must be left below the deepest chain (default 8192)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object: stack, stack_peak (the deepest chain), left, "
                             "chain ([bytes, function] from the outermost)")
    args = parser.parse_args()
    frame, calls, indirect = parse(args.elf)
    total, chain, cycles = deepest(frame, calls)
    stack = symbol(args.elf, "_stack_start") - symbol(args.elf, "_stack_end")
    if symbol(args.elf, "_stack_start") > symbol(args.elf, "__sdata"):
        print(f"stack-depth: {args.elf}: the stack's top lies above the statics, which it would "
              f"grow into: link with flip-link (the linker in .cargo/config.toml; `cargo install "
              f"flip-link`)", file=sys.stderr)
        return 1
    left = stack - total
    if args.json:
        print(json.dumps({"stack": stack, "stack_peak": total, "left": left,
                          "chain": [[frame[name], name] for name in chain]}))
    else:
        report(stack, total, left, len(indirect), chain, frame, cycles)
    if left < args.margin:
        print(f"stack-depth: less than {args.margin} bytes of stack left below the deepest chain "
              f"({left}): the node could overflow it", file=sys.stderr)
        return 1
    return 0


def report(stack: int, total: int, left: int, indirect: int, chain: list[str],
           frame: dict[str, int], cycles: set[str]) -> None:
    print(f"stack: {stack} bytes; the deepest direct call chain takes {total} "
          f"({left} left; {indirect} functions also call through pointers):")
    for name in chain:
        print(f"  {frame[name]:6}  {name}")
    for name in sorted(cycles):
        print(f"  (a call back into its own chain, not followed: {name})")


if __name__ == "__main__":
    sys.exit(main())
