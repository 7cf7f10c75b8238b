#!/usr/bin/env python3
"""The emulated board's watchdog test: a hung node loop restarts, with its stored table.

    python3 scripts/watchdog_test.py HANG_TEST_ELF TABLE_IMAGE

Runs HANG_TEST_ELF (pab-fw-an386 built with the `hang-test` feature) in QEMU's mps2-an386 with
TABLE_IMAGE planted in its table store, waits for it to boot with that table, opens the SLCAN
channel on UART0 and sends the trigger frame (extended id 0x1FFFFFFF), on which the node loop
spins forever. Passes when, within TIMEOUT_S, the board says the loop spins, the watchdog's
interrupt fires, the machine restarts (its boot line again) and boots with the same stored
table; prints the time from the hang to the second boot with the table (QEMU's clock runs at
host speed here, without -icount). Fails, saying which step did not come, otherwise.

The table is planted by QEMU's generic loader at the store's address (0x0004_0000) as one
committed slot of pab-storage's format (header: magic, format, sequence, length, image CRC,
header CRC; firmware/storage/src/lib.rs). Note: QEMU re-copies a loader's bytes at every system
reset, so this test shows that the watchdog resets the machine and that the node boots from its
store after it; that the RAM-backed store itself survives a reset is shown by the HIL suite's
board test (a table pushed with pabctl, then `system_reset`).
"""

import os
import struct
import subprocess
import sys
import tempfile
import threading
import time
import zlib

STORE_BASE = 0x0004_0000
TIMEOUT_S = 60.0
# Seconds the board idles, fed by its loop alone, before the hang.
IDLE_S = 3.0
TRIGGER = b"T1FFFFFFF0\r"


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
                        raise SystemExit(f"watchdog-test: {what or text!r} did not come within "
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
            qemu.stdin.write(TRIGGER)
            qemu.stdin.flush()
            spins = wait_for("hang-test: the node loop spins", booted, "the hang")
            fired = wait_for("watchdog: the node loop has not fed it", spins, "the watchdog's interrupt")
            restarted = wait_for("pab node", fired, "the restart")
            again = wait_for("booted with stored table version", restarted,
                             "the boot with the stored table after the restart")
            version_again = lines[again][1].rsplit(" ", 1)[-1]
            if version_again != version:
                raise SystemExit(f"watchdog-test: booted with version {version_again} after the "
                                 f"restart, {version} before")
            hang_at = lines[spins][0]
            print(f"watchdog-test: the node loop hung, the watchdog's interrupt came after "
                  f"{lines[fired][0] - hang_at:.3f} s, the machine restarted and booted with its "
                  f"stored table (version {version}) {lines[again][0] - hang_at:.3f} s after the hang")
            return 0
        finally:
            qemu.kill()
            qemu.wait()


if __name__ == "__main__":
    sys.exit(main())
