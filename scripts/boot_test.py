#!/usr/bin/env python3
"""The emulated board's bootloader (firmware/boot/mps2-an386) with real runs in QEMU's mps2-an386:
factory install, a signed update checked, swapped in and confirmed, one not confirmed and
reverted (after a reset, and after a hang that the watchdog resets), and refused updates that
never swap.

    python3 scripts/boot_test.py BOOTLOADER_ELF APP_BIN PABCTL NODE_BIN

BOOTLOADER_ELF is pab-boot-an386; APP_BIN the raw binary (`objcopy -O binary`) of
pab-an386-boottest (pab-fw-an386's test application, feature `boot`: linked at the active
partition), version 1; PABCTL the host tool, which makes the signing keys and signs. The test
makes version 2 by patching the binary's version byte ("PABBTVER1" -> "PABBTVER2"), signs it
(`pabctl sign`) and lays it out as a node leaves an update for its bootloader (pab-core's
update::stored: the image at the slot's start, 0xFF up to the manifest, the trailer and the
signature in the slot's last 96 bytes). The key page gets the update key's record at offset 64
as `update::stored::encode_key` writes it (magic "PABS", 1, 0, 0, 0, the public key, the CRC-32 of
those 40 bytes little endian, four zeros), the node key's record erased.

Each run starts a fresh QEMU with the bootloader as its kernel and, through QEMU's loader
(re-planted at every reset, which they do not mind): version 1 as the factory image
(0x0010_0000), the key page (0x0004_E000), the update's slot (0x0012_0000) and a script
(0x0020_0000): one action per boot for the test application (see its source): U store the
update and ask for it, B mark booted, N don't, H hang under the watchdog, E end. Each boot of
the application prints `boottest: version V step N state S verdict R action A`; a run passes
when those lines and the bootloader's own (`boot: ...`) are the expected ones and QEMU exits 0.

Last, NODE_BIN (the node firmware pab-fw-an386 built with `update`, raw) as the factory image:
installed, booted once, and running for a few seconds without a reset.
"""

import os
import re
import subprocess
import sys
import tempfile
import zlib

ACTIVE_LEN = 0x11000
MANIFEST_LEN = 96
TIMEOUT_S = 60
NODE_RUN_S = 3
BOARD = "fw-an386"

LINE = re.compile(
    r"^boottest: version (\S) step (\d+) state (\S+) verdict (none|ok|refused \d|unreadable)"
    r" action (\S)$"
)


def fail(message):
    print(f"boot-test: {message}", file=sys.stderr)
    sys.exit(1)


def keygen(pabctl, path):
    """A new signing key at `path`; returns its public key (32 bytes)."""
    out = subprocess.run(
        [pabctl, "keygen", "--signing", "-o", path], check=True, capture_output=True, text=True
    ).stdout
    match = re.search(r"public key: ([0-9a-f]{64})", out)
    if not match:
        fail(f"pabctl keygen printed no public key: {out!r}")
    return bytes.fromhex(match.group(1))


def key_page(public_key):
    """A 4 KiB key page: the node key's record erased, the update key's at offset 64."""
    head = b"PABS" + bytes([1, 0, 0, 0]) + public_key
    record = head + zlib.crc32(head).to_bytes(4, "little") + bytes(4)
    assert len(record) == 48
    page = bytearray(b"\xff" * 4096)
    page[64 : 64 + len(record)] = record
    return bytes(page)


def slot(signed):
    """The DFU slot as a node stores a signed image (`image ‖ trailer ‖ signature`)."""
    image, manifest = signed[:-MANIFEST_LEN], signed[-MANIFEST_LEN:]
    room = ACTIVE_LEN - MANIFEST_LEN
    if len(image) > room:
        fail(f"the image ({len(image)} bytes) does not fit the slot ({room})")
    return image + b"\xff" * (room - len(image)) + manifest


def sign(pabctl, work, key, image_path, board, name):
    out = os.path.join(work, name + ".signed")
    subprocess.run(
        [pabctl, "sign", "--key", key, "--board", board, "--version", "2.0.0",
         "--build", "0123456789abcdef", image_path, "-o", out],
        check=True, capture_output=True,
    )
    with open(out, "rb") as f:
        return f.read()


def run(work, boot_elf, factory, page, update, script):
    """One fresh QEMU: returns (the application's boot lines, the bootloader's lines, exit)."""
    files = {}
    for name, data in (("page", page), ("update", update), ("script", script + b"\0")):
        if data is None:
            continue
        path = os.path.join(work, f"run-{name}.bin")
        with open(path, "wb") as f:
            f.write(data)
        files[name] = path
    loaders = [f"loader,file={factory},addr=0x100000,force-raw=on",
               f"loader,file={files['update']},addr=0x120000,force-raw=on",
               f"loader,file={files['script']},addr=0x200000,force-raw=on"]
    if page is not None:
        loaders.append(f"loader,file={files['page']},addr=0x4e000,force-raw=on")
    command = ["qemu-system-arm", "-M", "mps2-an386", "-display", "none", "-monitor", "none",
               "-serial", "null", "-nic", "none",
               "-semihosting-config", "enable=on,target=native", "-kernel", boot_elf]
    for loader in loaders:
        command += ["-device", loader]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired as timeout:
        fail(f"QEMU did not end within {TIMEOUT_S} s; it printed: {timeout.stderr!r}")
    text = done.stdout + done.stderr
    app = [LINE.match(line).groups() for line in text.splitlines() if LINE.match(line)]
    boot = [line for line in text.splitlines() if line.startswith("boot: ")]
    return app, boot, done.returncode, text


def scenario(name, work, boot_elf, factory, page, update, script, want_app, want_boot,
             must_say=None):
    app, boot, status, text = run(work, boot_elf, factory, page, update, script)
    got = [(v, s, r, a) for (v, _step, s, r, a) in app]
    if must_say is not None and must_say not in text:
        fail(f"{name}: QEMU's output lacks {must_say!r}:\n{text}")
    if got != want_app or boot != want_boot or status != 0:
        fail(f"{name}: expected boots {want_app}, bootloader {want_boot}, exit 0;\n"
             f"got boots {got}, bootloader {boot}, exit {status}; output:\n{text}")
    print(f"boot-test: {name}: ok ({' -> '.join('v' + v for v, *_ in got)})")


def node_behind_bootloader(boot_elf, node_bin):
    """The node firmware (pab-fw-an386 with `update`) as the factory image: installed, booted
    once, and running NODE_RUN_S without a reset (its timers, UART and executor interrupts
    through the vector table at 0x8000; a reset would print the boot line again)."""
    command = ["qemu-system-arm", "-M", "mps2-an386", "-display", "none", "-monitor", "none",
               "-serial", "null", "-nic", "none",
               "-semihosting-config", "enable=on,target=native", "-kernel", boot_elf,
               "-device", f"loader,file={node_bin},addr=0x100000,force-raw=on"]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=NODE_RUN_S)
        fail(f"the node's QEMU ended (status {done.returncode}): {done.stdout + done.stderr}")
    except subprocess.TimeoutExpired as timeout:
        text = (timeout.stdout or b"").decode() + (timeout.stderr or b"").decode()
    installs = text.count("boot: factory install")
    boots = text.count("pab node ")
    if installs != 1 or boots != 1 or "watchdog" in text:
        fail(f"the node behind the bootloader: expected one install and one boot in "
             f"{NODE_RUN_S} s, no watchdog; got:\n{text}")
    print(f"boot-test: the node firmware behind the bootloader: ok (one boot, {NODE_RUN_S} s)")


def main():
    if len(sys.argv) != 5:
        fail("usage: boot_test.py BOOTLOADER_ELF APP_BIN PABCTL NODE_BIN")
    boot_elf, app_bin, pabctl, node_bin = sys.argv[1:]
    with open(app_bin, "rb") as f:
        v1 = f.read()
    if v1.count(b"PABBTVER1") != 1:
        fail(f"{app_bin}: no single version marker PABBTVER1")
    v2 = v1.replace(b"PABBTVER1", b"PABBTVER2")
    with tempfile.TemporaryDirectory(prefix="boot-test-") as work:
        factory = os.path.join(work, "v1.bin")
        v2_path = os.path.join(work, "v2.bin")
        with open(factory, "wb") as f:
            f.write(v1)
        with open(v2_path, "wb") as f:
            f.write(v2)
        key = os.path.join(work, "release.sign")
        other_key = os.path.join(work, "other.sign")
        public = keygen(pabctl, key)
        keygen(pabctl, other_key)
        page = key_page(public)
        good = slot(sign(pabctl, work, key, v2_path, BOARD, "good"))
        other_signer = slot(sign(pabctl, work, other_key, v2_path, BOARD, "other-key"))
        other_board = slot(sign(pabctl, work, key, v2_path, "fw-g474", "other-board"))
        tampered = bytearray(good)
        tampered[0x200] ^= 0x01
        tampered = bytes(tampered)

        factory_line = "boot: factory install"
        swapped = "boot: swapped in the update"
        reverted = "boot: reverted the unconfirmed update"

        def verdict(code):
            return f"boot: request: verdict {code}"

        scenario("(a, b) factory install; v2 checked, swapped in, confirmed", work, boot_elf,
                 factory, page, good, b"UBE",
                 [("1", "Boot", "none", "U"), ("2", "Swap", "ok", "B"),
                  ("2", "Boot", "none", "E")],
                 [factory_line, verdict(0), swapped])
        scenario("(c) v2 not confirmed, reset: reverted", work, boot_elf, factory, page, good,
                 b"UNE",
                 [("1", "Boot", "none", "U"), ("2", "Swap", "ok", "N"),
                  ("1", "Revert", "none", "E")],
                 [factory_line, verdict(0), swapped, reverted])
        scenario("(c) v2 hangs unconfirmed, the watchdog resets: reverted", work, boot_elf,
                 factory, page, good, b"UHE",
                 [("1", "Boot", "none", "U"), ("2", "Swap", "ok", "H"),
                  ("1", "Revert", "none", "E")],
                 [factory_line, verdict(0), swapped, reverted],
                 must_say="watchdog: the node loop has not fed it")
        for name, update, code in (
            ("(d) signed by another key: refused (6)", other_signer, 6),
            ("(d) for another board: refused (4)", other_board, 4),
            ("a byte of the image changed: refused (6)", tampered, 6),
        ):
            scenario(name, work, boot_elf, factory, page, update, b"UE",
                     [("1", "Boot", "none", "U"), ("1", "Boot", f"refused {code}", "E")],
                     [factory_line, verdict(code)])
        scenario("no update key in the key page: refused (6)", work, boot_elf, factory, None,
                 good, b"UE",
                 [("1", "Boot", "none", "U"), ("1", "Boot", "refused 6", "E")],
                 [factory_line, verdict(6)])
    node_behind_bootloader(boot_elf, node_bin)
    print("boot-test: all scenarios passed")


if __name__ == "__main__":
    main()
