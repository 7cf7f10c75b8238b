#!/usr/bin/env python3
"""Decodes captures with `python -m cantools decode`, strictly (without --no-strict), and fails on
any frame it cannot decode.

    python host-tools/tests/dbc_strict.py NET.dbc CAPTURE.log [NET.dbc CAPTURE.log ...]

Each pair is a DBC written by `pabctl dbc` (with `--claims-from CAPTURE.log` when the capture has
BLE claims) and a candump -L capture of that network's bus. The command line is the one a user
types, so what passes here is what they get: strict loading (cantools' consistency checks of the
database), every frame's identifier found, every frame's length equal to its message's DLC. An
empty capture still loads the database strictly.

Exits 0 when every frame of every capture decodes, 1 listing the first failures otherwise, 2 on
bad arguments or a missing cantools (never skipped silently).
"""

import re
import subprocess
import sys

# cantools decode (multi-line): a decoded frame's line ends with " ::", a failure has its cause
# after it ("... :: Unknown frame id 291 (0x123)", "... :: Wrong data size: 2 instead of 8 bytes").
FRAME = re.compile(r"^\(\d+\.\d+\)\s+\S+\s+[0-9A-Fa-f]+#[0-9A-Fa-f]*(?:\s+\S)?\s+::(.*)$")


def check(dbc: str, capture: str) -> list[str]:
    with open(capture, "rb") as stdin:
        frames = sum(1 for line in stdin if line.strip())
        stdin.seek(0)
        result = subprocess.run(
            [sys.executable, "-m", "cantools", "decode", dbc],
            stdin=stdin,
            capture_output=True,
            text=True,
            check=False,
        )
    if result.returncode != 0:
        return [f"{dbc}: cantools decode exited {result.returncode}: {result.stderr.strip()}"]
    decoded, failures = 0, []
    for line in result.stdout.splitlines():
        match = FRAME.match(line)
        if not match:
            continue
        cause = match.group(1).strip()
        if cause:
            failures.append(f"{capture}: {line}")
        else:
            decoded += 1
    if decoded + len(failures) != frames:
        failures.append(
            f"{capture}: cantools printed {decoded + len(failures)} frames of {frames} "
            "(an output format this script does not know?)"
        )
    print(f"{capture}: {decoded} of {frames} frames decoded strictly with {dbc}")
    return failures


def main() -> int:
    args = sys.argv[1:]
    if not args or len(args) % 2:
        print(__doc__, file=sys.stderr)
        return 2
    try:
        import cantools  # noqa: F401  (the subprocess runs it; fail here with a clear message)
    except ImportError as error:
        print(f"error: cantools is not installed ({error}); run scripts/python-env.sh",
              file=sys.stderr)
        return 2
    failures = []
    for dbc, capture in zip(args[::2], args[1::2]):
        failures += check(dbc, capture)
    for failure in failures[:20]:
        print(failure, file=sys.stderr)
    if len(failures) > 20:
        print(f"... and {len(failures) - 20} more", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
