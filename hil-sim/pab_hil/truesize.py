"""What the kernel charges a CAN socket's receive buffer per queued frame (the skb's truesize),
measured on a bus: `pab-node`'s default receive buffer (firmware/linux/src/receive_queue.rs) is
that figure times the frames of 100 ms of a saturated bus.

    hil-sim/run-hil --command "python -m pab_hil.truesize"      (in the micro-VM)
    python -m pab_hil.truesize --iface vcan0                    (root, on a machine with vcan0)

A socket that does not read is given a receive buffer (SO_RCVBUFFORCE: root); 5 000 frames are
sent to it (by cangen, then by a Python socket); it then reads what the kernel queued, and the
kernel's drop counter (SO_RXQ_OVFL) must account for the rest. The kernel queues a frame while
the buffer's charge is below its size, so the frames queued are ⌈size / truesize⌉.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import socket
import struct
import subprocess
import sys
import time

SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
SENT = 5000


def _receiver(iface: str, size: int) -> tuple[socket.socket, int]:
    s = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    s.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, size // 2)  # the kernel doubles it
    s.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
    s.bind((iface,))
    return s, s.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


def _drain(s: socket.socket) -> tuple[int, int]:
    """Frames read, and the last drop counter the kernel sent with one."""
    s.setblocking(False)
    count, drops = 0, 0
    while True:
        try:
            _data, ancillary, _flags, _addr = s.recvmsg(16, socket.CMSG_SPACE(4))
        except BlockingIOError:
            return count, drops
        count += 1
        for level, kind, value in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL:
                drops = struct.unpack("=I", value[:4])[0]


def _send(iface: str, sender: str) -> None:
    if sender == "cangen":
        subprocess.run(["cangen", iface, "-g", "0", "-I", "110", "-L", "8", "-D", "i",
                        "-n", str(SENT)], check=True)
        return
    tx = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    tx.bind((iface,))
    for i in range(SENT):
        while True:
            try:
                tx.send(struct.pack("=IB3x8s", 0x110, 8, i.to_bytes(8, "little")))
                break
            except OSError:  # ENOBUFS: the interface's queue is full
                time.sleep(0.001)
    tx.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pab_hil.truesize", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--iface", default="vcan0", help="SocketCAN interface (default: vcan0)")
    args = parser.parse_args(argv)
    senders = ["cangen", "python"] if shutil.which("cangen") else ["python"]
    print(f"kernel {os.uname().release} ({os.uname().machine}), {args.iface}, {SENT} frames per run")
    figures = set()
    for sender in senders:
        for size in (16384, 65536, 262144, 1048576):
            receiver, actual = _receiver(args.iface, size)
            _send(args.iface, sender)
            time.sleep(0.2)
            queued, _ = _drain(receiver)
            # Drops after the last frame queued are reported with the next frame.
            _send_one(args.iface)
            time.sleep(0.1)
            _, drops = _drain(receiver)
            receiver.close()
            low, high = actual / queued, actual / max(1, queued - 1)
            candidates = [t for t in range(math.floor(low) + 1, math.floor(high) + 1)
                          if math.ceil(actual / t) == queued]
            print(f"{sender:7} buffer {actual:8} B: {queued:5} frames queued, drop counter {drops:5}, "
                  f"queued + dropped = {queued + drops}; truesize in ({low:.1f}, {high:.1f}]")
            if queued + drops != SENT:
                print("error: the drop counter does not account for every frame", file=sys.stderr)
                return 1
            figures.add(tuple(t for t in candidates if t % 8 == 0) or tuple(candidates))
    common = set.intersection(*(set(f) for f in figures))
    print(f"truesize per CAN frame: {sorted(common) if common else 'inconsistent across runs'} bytes")
    return 0 if common else 1


def _send_one(iface: str) -> None:
    tx = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    tx.bind((iface,))
    tx.send(struct.pack("=IB3x8s", 0x111, 1, bytes(8)))
    tx.close()


if __name__ == "__main__":
    sys.exit(main())
