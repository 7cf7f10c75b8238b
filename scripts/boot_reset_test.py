#!/usr/bin/env python3
"""A reset at every step of the emulated board's bootloader: the update's verdict and mark, each
page copy, progress record and erase of embassy-boot's swap and revert, each one replaced in turn
by a system reset; after it the board must end running the old firmware or the new one, never
neither.

    python3 scripts/boot_reset_test.py RESET_TEST_ELF APP_BIN PABCTL

RESET_TEST_ELF is pab-boot-an386 built with its feature `reset-test` (pab_boot_an386::reset_test):
it numbers every erase and write of a partition from 1 across the resets of one QEMU process and,
in place of operation N (the word the test plants at 0x0003_0000 with QEMU's loader; 0: none),
says `boot: reset-test: reset at operation N` and resets the system, once per QEMU process. It
also says, at each boot, how many operations were made before embassy-boot's `prepare_boot` and
after it. APP_BIN and PABCTL are boot_test.py's: the test application pab-an386-boottest (v1, raw)
and the host tool that makes the signing key and signs v2.

Two scenarios, boot_test.py's with the same planted files (factory image v1, key page with the
update key, a signed v2 in the update slot) and scripts of actions:

- **swap** (`UBE`): v1 stores v2 and asks for it; the bootloader checks it, writes the verdict,
  marks the swap and swaps; v2 confirms itself and resets; then the run ends. Cut at every
  N = 1, 2, ... until a run ends without reaching N: the factory install's operations, the
  verdict, the mark, the swap's.
- **revert** (`UNE`): the same, but v2 resets without confirming itself, and the bootloader
  reverts it. Cut at every N from the first operation of the revert until a run ends without
  reaching N (the earlier ones are the swap scenario's).

One uncut run (N = 0) of each gives the operations' numbers of each step (the counts the
bootloader says at each boot): those before the cut run the same in a cut run, so the step an N
falls in is known, and with it what must follow. Each cut run must exit 0 (the test application's
last action, `E`), have the test application boot three times with the script's actions in order,
say the cut once, say nothing but the expected messages (no `prepare_boot failed`, no halt, no
panic), and end on the version its step implies:

| the cut falls on | messages (besides the reset test's) | versions at the 3 boots |
| --- | --- | --- |
| the factory install's first two operations (ACTIVE's erase and write) | install, install, verdict 0, swapped | 1 2 2 |
| the factory install's others (DFU's, STATE's and REQUEST's erases) | install, verdict 0, swapped | 1 2 2 |
| the verdict's write | install, verdict 0, swapped (decided again) | 1 2 2 |
| `mark_updated`'s operations | install (the update is lost: v1 reads `ok`) | 1 1 1 |
| the swap's | install, verdict 0, swapped (resumed) | 1 2 2 |
| the revert's, but its last (STATE's Revert magic) | install, verdict 0, swapped, reverted | 1 2 1 |
| the revert's last | install, verdict 0, swapped (STATE left erased: reads Boot) | 1 2 1 |

Runs go two at a time (two QEMU processes). Prints the reset points exercised per scenario and
step, how many runs ended on v1 and on v2, and the run time.
"""

import concurrent.futures
import os
import re
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import boot_test  # noqa: E402  (the signing, key page and slot helpers)

TIMEOUT_S = 30
WORKERS = 2
CUT_AT = 0x0003_0000

FACTORY = "boot: factory install"
VERDICT_OK = "boot: request: verdict 0"
SWAPPED = "boot: swapped in the update"
REVERTED = "boot: reverted the unconfirmed update"
CUT = re.compile(r"^boot: reset-test: reset at operation (\d+)$")
BEFORE = re.compile(r"^boot: reset-test: operations before prepare_boot (\d+)$")
AFTER = re.compile(r"^boot: reset-test: operations after prepare_boot (\d+)$")


def fail(message):
    print(f"boot-reset-test: {message}", file=sys.stderr)
    sys.exit(1)


class Run:
    """One QEMU process's output, parsed."""

    def __init__(self, cut_at, text, status):
        self.cut_at = cut_at
        self.text = text
        self.status = status
        lines = text.splitlines()
        self.cuts = [int(m.group(1)) for m in map(CUT.match, lines) if m]
        self.befores = [int(m.group(1)) for m in map(BEFORE.match, lines) if m]
        self.afters = [int(m.group(1)) for m in map(AFTER.match, lines) if m]
        # The bootloader's messages but the reset test's own.
        self.boot = [l for l in lines if l.startswith("boot: ") and not l.startswith("boot: reset-test:")]
        self.app = [boot_test.LINE.match(l).groups() for l in lines if boot_test.LINE.match(l)]
        # (version, state, verdict, action) of each boot of the test application.
        self.boots = [(v, s, r, a) for (v, _step, s, r, a) in self.app]

    def describe(self):
        return (f"N={self.cut_at}: exit {self.status}, cuts {self.cuts}, bootloader {self.boot}, "
                f"application {self.boots}; output:\n{self.text}")


def qemu(work, boot_elf, files, cut_at):
    command = ["qemu-system-arm", "-M", "mps2-an386", "-display", "none", "-monitor", "none",
               "-serial", "null", "-nic", "none",
               "-semihosting-config", "enable=on,target=native", "-kernel", boot_elf,
               "-device", f"loader,file={files['factory']},addr=0x100000,force-raw=on",
               "-device", f"loader,file={files['update']},addr=0x120000,force-raw=on",
               "-device", f"loader,file={files['script']},addr=0x200000,force-raw=on",
               "-device", f"loader,file={files['page']},addr=0x4e000,force-raw=on"]
    if cut_at:
        command += ["-device", f"loader,addr={CUT_AT:#x},data={cut_at},data-len=4"]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired as timeout:
        out = timeout.stderr or b""
        fail(f"N={cut_at}: QEMU did not end within {TIMEOUT_S} s (a halt or a reset loop); "
             f"it printed: {out[-4000:]!r}")
    return Run(cut_at, done.stdout + done.stderr, done.returncode)


def steps_of(uncut):
    """The operations' numbers of each step, from an uncut run: a list of (step, first, last)."""
    if uncut.cuts or uncut.status != 0 or len(uncut.befores) != len(uncut.afters):
        fail(f"the uncut run failed: {uncut.describe()}")
    # Each boot's messages, in order: the lines between two `after prepare_boot` counts.
    boots, current = [], []
    for line in uncut.text.splitlines():
        if line.startswith("boot: "):
            current.append(line)
            if AFTER.match(line):
                boots.append(current)
                current = []
    steps, end = [], 0
    for lines, before, after in zip(boots, uncut.befores, uncut.afters):
        if before > end:
            name = ("factory install" if FACTORY in lines
                    else "verdict and mark" if VERDICT_OK in lines else None)
            if name is None:
                fail(f"operations {end + 1}..{before} of an unknown step: {uncut.describe()}")
            steps.append((name, end + 1, before))
        if after > before:
            name = "swap" if SWAPPED in lines else "revert" if REVERTED in lines else None
            if name is None:
                fail(f"operations {before + 1}..{after} of an unknown step: {uncut.describe()}")
            steps.append((name, before + 1, after))
        end = after
    return steps, end


def expected(scenario, steps, n):
    """(the step, the bootloader's messages, the versions of the 3 boots) for a cut at n."""
    for name, first, last in steps:
        if first <= n <= last:
            k = n - first  # 0 for the step's first operation
            break
    else:
        return None, None, None
    if name == "factory install":
        # ACTIVE's erase (k = 0) and write (k = 1) leave it without an application: installed
        # again; after them only DFU, STATE and REQUEST remain to erase.
        boot = [FACTORY, FACTORY] if k <= 1 else [FACTORY]
        return name, boot + [VERDICT_OK, SWAPPED], ["1", "2", "2"]
    # The bootloader says its verdict once it has written it and marked the swap
    # (pab_boot_common::decide returns then): a cut in either says nothing that boot.
    if name == "verdict and mark":
        if k == 0:  # the verdict's write: the request is still pending, decided again
            return name, [FACTORY, VERDICT_OK, SWAPPED], ["1", "2", "2"]
        # mark_updated's: the verdict is written, the swap never marked; the update is lost.
        return name, [FACTORY], ["1", "1", "1"]
    if name == "swap":
        return name, [FACTORY, VERDICT_OK, SWAPPED], ["1", "2", "2"]
    assert name == "revert" and scenario == "revert"
    if n == last:  # the Revert magic's write, after STATE's erase: STATE reads Boot
        return name, [FACTORY, VERDICT_OK, SWAPPED], ["1", "2", "1"]
    return name, [FACTORY, VERDICT_OK, SWAPPED, REVERTED], ["1", "2", "1"]


def check(scenario, actions, steps, run):
    n = run.cut_at
    name, want_boot, want_versions = expected(scenario, steps, n)
    if name is None:
        fail(f"{scenario}: N={n} falls in no step")
    versions = [v for (v, _s, _r, _a) in run.boots]
    got_actions = "".join(a for (_v, _s, _r, a) in run.boots)
    problems = []
    if run.status != 0:
        problems.append("QEMU did not exit 0")
    if run.cuts != [n]:
        problems.append(f"the cut said {run.cuts}, not [{n}]")
    if got_actions != actions:
        problems.append(f"actions {got_actions!r}, not {actions!r}")
    if run.boot != want_boot:
        problems.append(f"bootloader said {run.boot}, not {want_boot}")
    if versions != want_versions:
        problems.append(f"versions {versions}, not {want_versions}")
    if len(run.afters) != len(run.boots):
        problems.append("a boot of the bootloader without a jump, other than the cut's")
    if problems:
        fail(f"{scenario}: cut in the {name} at N={n}: {'; '.join(problems)}; {run.describe()}")
    return name, versions[-1]


def scenario(name, actions, pool, work, boot_elf, files, want_uncut, from_step):
    files = dict(files)
    files["script"] = os.path.join(work, f"{name}-script.bin")
    with open(files["script"], "wb") as f:
        f.write(actions.encode() + b"\0")
    started = time.monotonic()
    uncut = qemu(work, boot_elf, files, 0)
    got = ["".join(a for (*_, a) in uncut.boots), uncut.boot]
    if got != want_uncut:
        fail(f"{name}: the uncut run: expected {want_uncut}, got {got}; {uncut.describe()}")
    steps, total = steps_of(uncut)
    first = 1
    if from_step is not None:
        first = next((f for (s, f, _l) in steps if s == from_step), None)
        if first is None:
            fail(f"{name}: the uncut run has no {from_step}: {steps}")
    print(f"boot-reset-test: {name}: uncut, {total} operations: "
          + ", ".join(f"{s} {f}..{l}" for (s, f, l) in steps))

    points, ends = {}, {"1": 0, "2": 0}
    n = first
    while True:
        # N = n, n + 1, ... in batches of the workers' count, until a run reaches no cut.
        batch = list(range(n, n + WORKERS * 4))
        runs = list(pool.map(lambda m: qemu(work, boot_elf, files, m), batch))
        done = False
        for run in runs:
            if not run.cuts and run.status == 0 and run.cut_at > total:
                if run.cut_at != total + 1:
                    fail(f"{name}: N={run.cut_at} reached no cut, but the uncut run made {total}")
                if run.boot != want_uncut[1]:
                    fail(f"{name}: N={run.cut_at}, past the last operation: {run.describe()}")
                done = True
                break
            step, end = check(name, actions, steps, run)
            points[step] = points.get(step, 0) + 1
            ends[end] += 1
        if done:
            break
        n += len(batch)
    exercised = sum(points.values())
    elapsed = time.monotonic() - started
    print(f"boot-reset-test: {name}: {exercised} reset points (N = {first}..{first + exercised - 1}: "
          + ", ".join(f"{s} {c}" for s, c in points.items())
          + f"); ended on v1 {ends['1']}, on v2 {ends['2']}; N = {first + exercised} reached "
          f"no cut; {elapsed:.1f} s")
    return points, ends


def main():
    if len(sys.argv) != 4:
        fail("usage: boot_reset_test.py RESET_TEST_ELF APP_BIN PABCTL")
    boot_elf, app_bin, pabctl = sys.argv[1:]
    started = time.monotonic()
    with open(app_bin, "rb") as f:
        v1 = f.read()
    if v1.count(b"PABBTVER1") != 1:
        fail(f"{app_bin}: no single version marker PABBTVER1")
    v2 = v1.replace(b"PABBTVER1", b"PABBTVER2")
    with tempfile.TemporaryDirectory(prefix="boot-reset-test-") as work:
        files = {"factory": os.path.join(work, "v1.bin"), "page": os.path.join(work, "page.bin"),
                 "update": os.path.join(work, "update.bin")}
        v2_path = os.path.join(work, "v2.bin")
        with open(files["factory"], "wb") as f:
            f.write(v1)
        with open(v2_path, "wb") as f:
            f.write(v2)
        key = os.path.join(work, "release.sign")
        with open(files["page"], "wb") as f:
            f.write(boot_test.key_page(boot_test.keygen(pabctl, key)))
        with open(files["update"], "wb") as f:
            f.write(boot_test.slot(boot_test.sign(pabctl, work, key, v2_path, boot_test.BOARD,
                                                  "good")))
        with concurrent.futures.ThreadPoolExecutor(WORKERS) as pool:
            scenario("swap", "UBE", pool, work, boot_elf, files,
                     ["UBE", [FACTORY, VERDICT_OK, SWAPPED]], None)
            scenario("revert", "UNE", pool, work, boot_elf, files,
                     ["UNE", [FACTORY, VERDICT_OK, SWAPPED, REVERTED]], "revert")
    print(f"boot-reset-test: all reset points passed in {time.monotonic() - started:.1f} s")


if __name__ == "__main__":
    main()
