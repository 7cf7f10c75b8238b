"""Firmware update over the bus, on the emulated Cortex-M4 behind its bootloader
(firmware/boot/mps2-an386): `pabctl flash` sends a signed image over the bus (SLCAN, the kernel's
slcan driver, cangw: the board's usual bridge) into the board's update partition; the board asks
its bootloader, which checks the signature and swaps the image in; the new firmware confirms
itself once it has joined the bus. Images for another board, lower versions, changed bytes and a
new firmware that never comes up are refused or rolled back, and the board keeps running its
previous firmware.

The images (target/hil-board/update-*: hil-sim/run-hil builds and signs them): the node that takes
updates as v1 (0.1.0) and v2 (0.2.0), a v2 that hangs at start, and v2 and v1 signed for another
board and as a downgrade, under a test signing key whose public key goes into the board's key
page (`pabctl keypage --update-key`)."""

from __future__ import annotations

import json
import re
import subprocess
import threading
import time
from pathlib import Path

import can

from pab_hil import protocol
from pab_hil.board import BehindBootloader, BoardNode
from pab_hil.nodes import REPO, MissingBinary, binary

IMAGES = REPO / "target" / "hil-board"


def image(name: str) -> Path:
    path = IMAGES / name
    if not path.is_file():
        raise MissingBinary(f"{path} is missing: hil-sim/run-hil builds it")
    return path


def pabctl(*args: str, timeout: float = 300.0) -> subprocess.CompletedProcess:
    return subprocess.run([str(binary("pabctl")), *args], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True, timeout=timeout)


def version(iface: str) -> str | None:
    """The firmware version node 1 states (`pabctl nodes --json`), or None if it is not heard."""
    listed = pabctl("nodes", "--iface", iface, "--listen", "1.5", "--json")
    assert listed.returncode == 0, listed.stderr
    nodes = [n for n in json.loads(listed.stdout) if n["node_id"] == 1]
    return nodes[0]["firmware"]["version"] if nodes else None


def flash(iface: str, signed: Path) -> subprocess.CompletedProcess:
    result = pabctl("flash", "--iface", iface, "--node", "1", str(signed))
    print(f"$ pabctl flash {signed.name}: exit {result.returncode}\n{result.stdout}{result.stderr}")
    return result


class UpdateFrames:
    """Counts the update's frames on the bus (UpdateTransfer both ways, UpdateStatus) while it
    runs."""

    def __init__(self, iface: str) -> None:
        self.iface = iface
        self.counts = {protocol.UPDATE_TRANSFER: 0, protocol.UPDATE_STATUS: 0}
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._count)

    def _count(self) -> None:
        with can.Bus(interface="socketcan", channel=self.iface) as bus:
            while not self.stop.is_set():
                message = bus.recv(0.1)
                if message is not None and message.is_extended_id:
                    service = (message.arbitration_id >> 16) & 0xFF
                    if service in self.counts:
                        self.counts[service] += 1

    def __enter__(self) -> "UpdateFrames":
        self.thread.start()
        time.sleep(0.2)
        return self

    def __exit__(self, *_) -> None:
        self.stop.set()
        self.thread.join()


#: Bits on the wire of an 8-byte frame with a 29-bit identifier, stuffing at its worst (Davis et
#: al. 2007: 54 + 8 * 8 + 13 + floor((54 + 8 * 8 - 1) / 4) = 160), for the time on a G474's bus.
WORST_BITS_PER_FRAME = 160


def test_the_board_is_updated_over_the_bus_and_keeps_its_firmware_when_an_update_fails(
        iface, out_dir, figures):
    bootloader = image("pab-boot-an386")
    v1 = image("update-v1.bin")
    page = out_dir / "update.keypage.bin"
    made = pabctl("keypage", "--update-key", str(image("update.pub")), "-o", str(page))
    assert made.returncode == 0, made.stderr
    # A copy of v2 with one byte of its image changed after signing: only the bootloader, which
    # checks the signature, can tell.
    tampered = out_dir / "update-tampered.signed"
    signed = bytearray(image("update-v2.signed").read_bytes())
    signed[len(signed) // 2] ^= 0x01
    tampered.write_bytes(bytes(signed))

    board = BoardNode("arm", 1, iface, out_dir, elf=bootloader,
                      boot=BehindBootloader(factory=v1, key_page=page))
    board.start()
    try:
        assert version(iface) == "0.1.0"

        # Refused at the Begin, from the trailer alone: nothing is written, nothing restarts.
        other = flash(iface, image("update-other-board.signed"))
        assert other.returncode != 0 and "board" in (other.stdout + other.stderr), other
        older = flash(iface, image("update-downgrade.signed"))
        assert older.returncode != 0 and "version" in (older.stdout + older.stderr), older
        assert version(iface) == "0.1.0"

        # Sent whole; the bootloader refuses it (bad signature) and the board runs v1 again.
        changed = flash(iface, tampered)
        assert changed.returncode != 0 and "signature" in (changed.stdout + changed.stderr), \
            changed
        assert version(iface) == "0.1.0"

        # A v2 that never comes up: swapped in, never confirmed; the watchdog resets it and the
        # bootloader reverts to v1.
        hangs = flash(iface, image("update-v2-hang.signed"))
        assert hangs.returncode != 0 and "0.1.0" in (hangs.stdout + hangs.stderr), hangs
        deadline = time.monotonic() + 30
        while version(iface) != "0.1.0":
            assert time.monotonic() < deadline, "v1 did not come back after the hanging v2"

        # And v2: swapped in, confirmed, running. Its frames counted, its time taken.
        started = time.monotonic()
        with UpdateFrames(iface) as frames:
            updated = flash(iface, image("update-v2.signed"))
        took = time.monotonic() - started
        assert updated.returncode == 0, updated
        assert version(iface) == "0.2.0"
        sent = re.search(r"(\d+) bytes in (\d+) ms \((\d+) B/s\)", updated.stdout)
        assert sent is not None, updated.stdout
        image_bytes, transfer_ms = int(sent.group(1)), int(sent.group(2))
        count = sum(frames.counts.values())
        per_byte = count / image_bytes
        figures("firmware_update_emulated_board", {
            "image_bytes": image_bytes,
            "transfer_ms": transfer_ms,
            "bytes_per_s": round(image_bytes / (transfer_ms / 1000)),
            "flash_command_s": round(took, 1),
            "frames": count,
            "frames_per_image_byte": round(per_byte, 4),
            # The same frames on a classic CAN bus at 500 kbit/s and 1 Mbit/s, nothing else on
            # it: the bus's limit for this transfer (the board's own write time aside).
            "bus_limit_s_500k": round(count * WORST_BITS_PER_FRAME / 500_000, 2),
            "bus_limit_s_1m": round(count * WORST_BITS_PER_FRAME / 1_000_000, 2),
            # The bus's payload limit: every frame 8 bytes of the image.
            "payload_limit_s_500k": round(image_bytes / 8 * WORST_BITS_PER_FRAME / 500_000, 2),
            "payload_limit_s_1m": round(image_bytes / 8 * WORST_BITS_PER_FRAME / 1_000_000, 2),
            # A G474's writes (datasheet typical): a 2 KiB page's erase, 22 ms; a double word's
            # program, 82 us; blocking, between a chunk and its answer.
            "g474_write_s": round(-(-image_bytes // 2048) * 0.022 + image_bytes / 8 * 82e-6, 2),
        })
        # Confirmed: a reset keeps it (an unconfirmed one would be reverted).
        board.reset()
        deadline = time.monotonic() + 30
        while (found := version(iface)) is None:
            assert time.monotonic() < deadline, "the board did not come back after its reset"
        assert found == "0.2.0"
    finally:
        board.stop()


def test_the_arm_board_is_updated_while_take_and_return_runs_on_the_other_nodes(
        session_for, out_dir):
    """The Take and Return network with its arm node on the emulated board behind its bootloader
    (v1), the hand and gaze nodes `pab-node`: the arm is updated to v2 with `pabctl flash` while
    the others run phase A (looking around, the arm at rest), which stays A throughout; the board
    comes back on v2 with its stored table, and the scenario then runs A to F as without the
    update."""
    from test_take_and_return import ARM, run_a_to_f

    from pab_hil.person import TakeAndReturn

    page = out_dir / "update.keypage.bin"
    made = pabctl("keypage", "--update-key", str(image("update.pub")), "-o", str(page))
    assert made.returncode == 0, made.stderr
    # The person shows the object only once the update is done (show_at set below).
    person = TakeAndReturn(show_at=float("inf"))
    session = session_for(person, boards=("arm",), board_elf=image("pab-boot-an386"),
                          board_boot=BehindBootloader(factory=image("update-v1.bin"),
                                                      key_page=page))
    session.wait_for(lambda: session.observer.node(ARM).table is not None, 10,
                     "the board's table status")
    crc = session.observer.node(ARM).table.crc
    assert version(session.iface) == "0.1.0"

    updated = flash(session.iface, image("update-v2.signed"))
    assert updated.returncode == 0, updated
    assert version(session.iface) == "0.2.0"
    # The others kept phase A through the update, and the board runs its stored table again.
    assert session.phases.sequence() == ["A"], session.phase_report()
    session.wait_for(lambda: (v := session.observer.node(ARM)).table is not None
                     and v.table.crc == crc and v.heartbeat.state == "operational", 10,
                     "the board's stored table after the update")

    person.show_at = session.world.snapshot().t + 1.0
    run_a_to_f(session, person)
    session.close()
