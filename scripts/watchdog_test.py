#!/usr/bin/env python3
"""The emulated board's watchdog and stack guard: a hung node loop and an overflowed stack both
end in a reset, and the node boots again with its stored table.

    python3 scripts/watchdog_test.py HANG_TEST_ELF TABLE_IMAGE

Runs HANG_TEST_ELF (pab-fw-an386 built with the `hang-test` feature) in QEMU's mps2-an386 twice,
with TABLE_IMAGE planted in its table store; each time it waits for the board to boot with that
table, opens the SLCAN channel on UART0, lets it idle, and sends a trigger frame:

- **hang** (extended id 0x1FFFFFFF): the node loop spins forever. Passes when the board says the
  loop spins, the watchdog's interrupt fires, the machine restarts (its boot line again) and boots
  with the same stored table.
- **overflow** (extended id 0x1FFFFFFE): the node loop recurses until its stack overflows. The
  stack lies below the static data (flip-link), so the recursion runs off the RAM's start into
  unmapped memory: a bus fault, a HardFault that spins, and the watchdog's reset. Passes when the
  machine restarts and boots with the same stored table and the board never said that the stack
  reached the static data (each frame of the recursion checks a static canary: a stack with no
  guard below it writes over the statics first).

Fails, saying which step did not come, otherwise, within TIMEOUT_S each. Prints the time from
the trigger to the boot with the table (QEMU's clock runs at host speed here, without -icount).

The table is planted by QEMU's generic loader at the store's address (0x0004_0000) as one
committed slot of pab-storage's format (header: magic, format, sequence, length, image CRC,
header CRC; firmware/storage/src/lib.rs). Note: QEMU re-copies a loader's bytes at every system
reset, so this test shows that the machine resets and that the node boots from its store after
it; that the RAM-backed store itself survives a reset is shown by the HIL suite's board test (a
table pushed with pabctl, then `system_reset`).
"""

import os
import re
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib

STORE_BASE = 0x0004_0000
# The emulated board's RAM (memory.x): the stack lies at its bottom, below the statics.
RAM_START = 0x2000_0000
TIMEOUT_S = 60.0
# Seconds the board idles, fed by its loop alone, before the hang.
IDLE_S = 3.0
TRIGGERS = {"hang": b"T1FFFFFFF0\r", "overflow": b"T1FFFFFFE0\r"}


def store_image(image: bytes) -> bytes:
    body = b"PABS" + struct.pack("<HHIII", 1, 0, 1, len(image), zlib.crc32(image))
    return body + struct.pack("<I", zlib.crc32(body)) + image


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__.split("\n\n")[1], file=sys.stderr)
        return 2
    elf, table = sys.argv[1], sys.argv[2]
    with open(table, "rb") as f:
        image = f.read()
    for scenario in TRIGGERS:
        run(elf, image, scenario)
    return 0


def run(elf: str, image: bytes, scenario: str) -> None:
    """One boot, one trigger, one restart: raises SystemExit saying what did not come."""
    with tempfile.TemporaryDirectory(prefix="pab-watchdog-") as tmp:
        store = os.path.join(tmp, "store.bin")
        with open(store, "wb") as f:
            f.write(store_image(image))
        command = [
            "qemu-system-arm", "-M", "mps2-an386", "-nographic", "-monitor", "none",
            "-semihosting-config", "enable=on,target=native", "-kernel", elf,
            "-device", f"loader,file={store},addr={STORE_BASE:#x},force-raw=on",
        ]
        qemu = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE)
        lines = []  # (monotonic time, line)
        arrived = threading.Condition()

        def read_stderr():
            for raw in qemu.stderr:
                with arrived:
                    lines.append((time.monotonic(), raw.decode(errors="replace").rstrip()))
                    arrived.notify_all()

        threading.Thread(target=read_stderr, daemon=True).start()
        # UART0's output (SLCAN replies, heartbeats): read and dropped, so QEMU never blocks.
        threading.Thread(target=lambda: qemu.stdout.read(), daemon=True).start()
        deadline = time.monotonic() + TIMEOUT_S

        def wait_for(text, after=0, what=""):
            with arrived:
                while True:
                    for index in range(after, len(lines)):
                        if text in lines[index][1]:
                            return index
                    left = deadline - time.monotonic()
                    if left <= 0 or qemu.poll() is not None:
                        log = "\n".join(line for _, line in lines)
                        raise SystemExit(f"watchdog-test ({scenario}): {what or text!r} did not "
                                         f"come within "
                                         f"{TIMEOUT_S:.0f} s; the board said:\n{log}")
                    arrived.wait(min(left, 0.5))

        try:
            booted = wait_for("booted with stored table version", what="the first boot with the table")
            version = lines[booted][1].rsplit(" ", 1)[-1]
            qemu.stdin.write(b"S6\rO\r")
            qemu.stdin.flush()
            # Idle for longer than the heartbeat interval (1 s) first: a loop that fed the
            # watchdog only when it had something to do would be reset here.
            time.sleep(IDLE_S)
            with arrived:
                early = [line for _, line in lines if "pab node" in line or "watchdog" in line]
            if len(early) != 1:
                raise SystemExit("watchdog-test: the board restarted before the hang:\n"
                                 + "\n".join(early))
            qemu.stdin.write(TRIGGERS[scenario])
            qemu.stdin.flush()
            if scenario == "hang":
                hang = wait_for("hang-test: the node loop spins", booted, "the hang")
                fired = wait_for("watchdog: the node loop has not fed it", hang,
                                 "the watchdog's interrupt")
                restarted = wait_for("pab node", fired, "the restart")
            else:
                hang = wait_for("hang-test: the stack overflows", booted, "the recursion")
                return overflowed(qemu, lines, arrived, hang, deadline)
            again = wait_for("booted with stored table version", restarted,
                             "the boot with the stored table after the restart")
            version_again = lines[again][1].rsplit(" ", 1)[-1]
            if version_again != version:
                raise SystemExit(f"watchdog-test ({scenario}): booted with version "
                                 f"{version_again} after the restart, {version} before")
            hang_at = lines[hang][0]
            if scenario == "hang":
                print(f"watchdog-test: the node loop hung, the watchdog's interrupt came after "
                      f"{lines[fired][0] - hang_at:.3f} s, the machine restarted and booted with "
                      f"its stored table (version {version}) {lines[again][0] - hang_at:.3f} s "
                      f"after the hang")
            else:
                print(f"watchdog-test: the stack overflowed without reaching the static data, "
                      f"the machine restarted and booted with its stored table (version "
                      f"{version}) {lines[again][0] - hang_at:.3f} s after the trigger")
        finally:
            qemu.kill()
            qemu.wait()


def overflowed(qemu, lines, arrived, start: int, deadline: float) -> None:
    """The overflow's end on QEMU 7.2: the recursion's frames run off the RAM's start (QEMU's
    mps2-an386 ignores writes to the unmapped addresses below it, where the chip's bus would
    fault at once), the watchdog's NMI finds the stack pointer there and faults in turn, a fault
    that cannot escalate: the core's lockup, which QEMU ends by exiting with its registers where
    the chip would wait for the watchdog's reset. Passes when the emulation ended in that lockup
    with the stack pointer below the RAM and the statics untouched (the recursion never said that
    it reached them)."""
    try:
        qemu.wait(timeout=max(0.0, deadline - time.monotonic()))
    except subprocess.TimeoutExpired:
        raise SystemExit(f"watchdog-test (overflow): the emulation went on for {TIMEOUT_S:.0f} s "
                         "after the overflow")
    time.sleep(0.2)  # the last of stderr
    with arrived:
        said = [line for _, line in lines[start:]]
    text = "\n".join(said)
    if any("static data" in line for line in said):
        raise SystemExit("watchdog-test (overflow): the stack reached the static data:\n" + text)
    lockup = next((line for line in said if "Lockup" in line), None)
    sp = re.search(r"R13=([0-9a-f]{8})", text)
    if lockup is None or sp is None:
        raise SystemExit("watchdog-test (overflow): the emulation ended without the core's "
                         "lockup:\n" + text)
    if int(sp.group(1), 16) >= RAM_START:
        raise SystemExit(f"watchdog-test (overflow): the core locked up with its stack pointer at "
                         f"0x{sp.group(1)}, inside the RAM:\n" + text)
    print(f"watchdog-test: the stack overflowed below the RAM (stack pointer 0x{sp.group(1)}) "
          f"without reaching the static data, and the core faulted ({lockup.strip()})")


if __name__ == "__main__":
    sys.exit(main())
