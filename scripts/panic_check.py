#!/usr/bin/env python3
"""Finds the panic call sites of a linked Cortex-M firmware ELF that the project's code reaches.

    python3 scripts/panic_check.py --repo . --objdump LLVM_OBJDUMP --nm LLVM_NM \
        --addr2line ADDR2LINE [--crate NAME=DIR ...] [--report NAME=DIR ...] ELF...

Used by scripts/panic-check.sh (which says how to run it); the method, in short:

1. Panic entry points. Seeds: the functions whose demangled name matches PANIC_PATTERNS (the
   panicking functions of `core`, the panic handlers of panic-probe, defmt and the boards).
   Then the closure: a function of `core` or `alloc` that calls or branches to an entry point
   and contains no return instruction (it can only end in a panic) is one too. Under fat LTO
   the wrappers are outlined functions with these names, so this finds all of them.
2. Call sites: every branch instruction (`bl`, `blx`, `b`, `b<cond>`, their `.w` forms,
   `cbz`/`cbnz`) of the disassembly whose target is the first instruction of an entry point,
   outside the entry points themselves. A conditional tail branch to `panic_bounds_check` is a
   call site as much as a `bl` is.
3. Attribution: fat LTO inlines the project's crates into others' functions (and the reverse),
   so the name of the function that holds a call site says little. Each site's address goes
   through addr2line with inlining (`-i`): the chain of source frames, innermost first, from the
   debug info (the firmware profile keeps line tables and inlining records; they are not
   loaded onto the board). A site is the project's when any frame of its chain lies in one of
   the checked crates' source directories. The chain is printed with each finding.
4. Verdict: a site owned by a checked crate (`--crate`) fails the check, whatever its entry
   point, `panic_const_async_fn_resumed` included: rustc gives every async fn that can return a
   "resumed after completion" state that panics and that LLVM cannot prove unreachable, so the
   checked crates have no such async fn (pab_storage is blocking; pab_app's loop is `-> !`).
   Sites owned by a `--report` crate (the boards: boot-time unwraps, their bus drivers' async
   fns) and by libraries, even inlined into the checked crates, are printed and do not fail.

Exit status: 0 when no site is attributed to a checked crate, 1 otherwise (each one printed with
its inline chain), 2 on a usage or tool error.
"""

import argparse
import os
import re
import subprocess
import sys

# Seeds of the panic entry points, matched against demangled symbol names (hash suffixes removed).
PANIC_PATTERNS = [
    r"^core::panicking::",
    r"^core::option::(unwrap_failed|expect_failed)$",
    r"^core::result::unwrap_failed$",
    r"^core::slice::.*_fail$",
    r"^core::slice::index::slice_.*fail",
    r"^core::str::.*slice_error_fail",
    r"^core::cell::panic_already_(mutably_)?borrowed$",
    r"^core::intrinsics::",
    r"^core::hint::unreachable_unchecked::precondition_check$",
    r"^rust_begin_unwind$",
    r"^_defmt_panic$",
    r"^__defmt_default_panic$",
    r"^panic_probe::",
]

BRANCH = re.compile(
    r"^\s*([0-9a-f]+):\s+(bl|blx|b|b\.w|b(?:eq|ne|cs|hs|cc|lo|mi|pl|vs|vc|hi|ls|ge|lt|gt|le)(?:\.w)?|cbn?z)\s+"
    r"(?:r\d+,\s*)?0x([0-9a-f]+)"
)
RETURN = re.compile(r"^\s*[0-9a-f]+:\s+(bx\s+lr|pop(?:\.w)?\s+\{[^}]*\bpc\}|ldr(?:\.w)?\s+pc,|ldm\S*\s+sp!?,\s*\{[^}]*\bpc\})")
FUNCTION = re.compile(r"^([0-9a-f]+) <(.+)>:$")
INSTRUCTION = re.compile(r"^\s*([0-9a-f]+):")


def run(command):
    try:
        return subprocess.run(command, check=True, capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError) as error:
        sys.exit(f"panic-check: {' '.join(command)} failed: {error}")


def strip_hash(name):
    """`foo::bar::h0123456789abcdef` and `foo::bar` are the same function for the patterns."""
    return re.sub(r"::h[0-9a-f]{16}$", "", name)


def symbols(nm, elf):
    """Function symbols: {address: demangled name} (Thumb bit cleared)."""
    raw = run([nm, "--defined-only", "-n", elf]).splitlines()
    demangled = run([nm, "--defined-only", "-n", "-C", elf]).splitlines()
    if len(raw) != len(demangled):
        sys.exit("panic-check: llvm-nm listed the symbols differently with and without -C")
    functions = {}
    for line in demangled:
        parts = line.split(" ", 2)
        if len(parts) == 3 and parts[1] in ("t", "T", "W", "w"):
            address = int(parts[0], 16) & ~1
            functions.setdefault(address, strip_hash(parts[2]))
    return functions


def disassemble(objdump, elf):
    """{function start: (name, [(site, target)], returns)} from the text sections."""
    bodies = {}
    current = None
    for line in run([objdump, "-d", "--no-show-raw-insn", "-C", elf]).splitlines():
        header = FUNCTION.match(line)
        if header:
            current = int(header.group(1), 16)
            bodies[current] = (strip_hash(header.group(2)), [], [False])
            continue
        if current is None or not INSTRUCTION.match(line):
            continue
        branch = BRANCH.match(line)
        if branch:
            bodies[current][1].append((int(branch.group(1), 16), int(branch.group(3), 16)))
        if RETURN.match(line):
            bodies[current][2][0] = True
    return {start: (name, branches, returns[0]) for start, (name, branches, returns) in bodies.items()}


def entry_points(functions, bodies):
    """{address: (name, why)} of every panic entry point."""
    entries = {
        address: (name, "pattern")
        for address, name in functions.items()
        if any(re.search(pattern, name) for pattern in PANIC_PATTERNS)
    }
    changed = True
    while changed:
        changed = False
        for start, (name, branches, returns) in bodies.items():
            if start in entries or returns or not re.match(r"^(<)?(core|alloc)::", name):
                continue
            callee = next((target for _, target in branches if target in entries), None)
            if callee is not None:
                entries[start] = (name, f"core/alloc, never returns, calls {entries[callee][0]}")
                changed = True
    return entries


def inline_chains(addr2line, elf, addresses):
    """{address: [(function, file, line)]} innermost frame first."""
    if not addresses:
        return {}
    text = "\n".join(f"0x{address:x}" for address in addresses) + "\n"
    try:
        output = subprocess.run(
            [addr2line, "-e", elf, "-i", "-f", "-C", "-a"],
            input=text, check=True, capture_output=True, text=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError) as error:
        sys.exit(f"panic-check: {addr2line} failed: {error}")
    chains = {}
    current = None
    lines = output.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        if re.match(r"^0x[0-9a-f]+$", line):
            current = int(line, 16)
            chains[current] = []
            i += 1
            continue
        function = line
        location = lines[i + 1] if i + 1 < len(lines) else "??:0"
        file, _, number = location.rpartition(":")
        number = number.split(" ")[0]
        chains[current].append((function, file, number))
        i += 2
    return chains


ASYNC_RESUMED = "panic_const_async_fn_resumed"


def is_standard_library(file):
    """Frames of core, alloc and the compiler's own sources (`/rustc/<hash>/library/...`)."""
    return file.startswith("/rustc/") or "/library/core/" in file or "/library/alloc/" in file


def crate_of(file, crates):
    path = os.path.realpath(file) if file.startswith("/") else file
    return next((name for name, directory in crates if path.startswith(directory)), None)


def owner_of(chain, crates):
    """The crate that wrote the panicking operation: the innermost frame outside the standard
    library (`slice[i]`, `copy_from_slice`, `%` and `unwrap` are core's frames, inlined into the
    code that used them). Its crate name for the checked crates, else its file."""
    for _, file, _ in chain:
        if not is_standard_library(file):
            return crate_of(file, crates) or file
    return "core"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repo", required=True, help="the repository's root")
    parser.add_argument("--objdump", required=True)
    parser.add_argument("--nm", required=True)
    parser.add_argument("--addr2line", required=True)
    parser.add_argument(
        "--crate", action="append", default=[], metavar="NAME=DIR",
        help="a checked crate and its source directory, relative to the repository",
    )
    parser.add_argument(
        "--report", action="append", default=[], metavar="NAME=DIR",
        help="a crate whose sites are attributed and printed, but do not fail the check",
    )
    parser.add_argument("elves", nargs="+", metavar="ELF")
    args = parser.parse_args()

    repo = os.path.realpath(args.repo)
    crates = []
    for spec in args.crate:
        name, _, directory = spec.partition("=")
        if not name or not directory:
            sys.exit(f"panic-check: --crate {spec}: expected NAME=DIR")
        crates.append((name, os.path.join(repo, directory.rstrip("/")) + "/"))

    reported = []
    for spec in args.report:
        name, _, directory = spec.partition("=")
        if not name or not directory:
            sys.exit(f"panic-check: --report {spec}: expected NAME=DIR")
        reported.append((name, os.path.join(repo, directory.rstrip("/")) + "/"))
    checked = {name for name, _ in crates}
    crates = crates + reported

    failed = False
    for elf in args.elves:
        functions = symbols(args.nm, elf)
        bodies = disassemble(args.objdump, elf)
        entries = entry_points(functions, bodies)
        sites = [
            (site, target, name)
            for start, (name, branches, _) in bodies.items()
            if start not in entries
            for site, target in branches
            if target in entries
        ]
        chains = inline_chains(args.addr2line, elf, sorted({site for site, _, _ in sites}))
        print(f"panic-check: {os.path.basename(elf)}: {len(entries)} panic entry points, "
              f"{len(sites)} call sites")
        for address, (name, why) in sorted(entries.items()):
            print(f"  entry 0x{address:08x} {name} ({why})")
        failures, guards, inlined, others = [], [], [], 0
        for site, target, holder in sorted(sites):
            chain = chains.get(site, [])
            owner = owner_of(chain, crates)
            checked_frames = sorted({crate_of(file, crates) for _, file, _ in chain} - {None})
            entry = entries[target][0]
            if owner in dict(crates) and owner not in checked and entry.endswith(ASYNC_RESUMED):
                guards.append((site, owner, chain))
            elif owner in dict(crates):
                failures.append((site, entry, holder, chain, owner))
                failed = failed or owner in checked
            elif checked_frames:
                inlined.append((site, entry, owner, checked_frames))
            else:
                others += 1
        for site, entry, holder, chain, owner in failures:
            kind = "PANIC SITE" if owner in checked else "reported site"
            print(f"  {kind} of {owner}: 0x{site:08x} -> {entry} (in {holder}); "
                  "inline chain, innermost first:")
            if entry.endswith(ASYNC_RESUMED):
                print("      (the \"resumed after completion\" state of an async fn that can "
                      "return: make it a plain fn, or `-> !`)")
            for function, file, number in chain:
                shown = os.path.relpath(file, repo) if file.startswith(repo + "/") else file
                print(f"      {function} at {shown}:{number}")
        for site, owner, chain in guards:
            function, file, number = next(
                frame for frame in chain if crate_of(frame[1], crates) == owner)
            print(f"  async-fn guard of {owner}: 0x{site:08x} in {function} "
                  f"({os.path.relpath(file, repo)}:{number})")
        for site, entry, owner, checked_frames in inlined:
            print(f"  library site of {owner}, inlined into {', '.join(checked_frames)}: "
                  f"0x{site:08x} -> {entry}")
        failing = sum(1 for failure in failures if failure[4] in checked)
        print(f"panic-check: {os.path.basename(elf)}: {failing} panic call sites of the "
              f"checked crates ({', '.join(sorted(checked))}), "
              f"{len(failures) - failing} of the reported ones, {len(guards)} compiler-inserted async-fn "
              f"guards in the reported ones, "
              f"{len(inlined)} library sites inlined into them, {others} other library sites")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
