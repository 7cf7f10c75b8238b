"""The harness's ears: candump, in a process of its own, writes every frame on the bus to a log; the
harness's own socket hears the gateways' re-published frames (passed to the world, which obeys
them) and the nodes' status frames (decoded, for the tests)."""

from __future__ import annotations

import platform
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import can

from . import protocol as p
from . import world as w

@dataclass
class NodeView:
    """The latest of what a node said about itself, with the bus time it said it."""

    heartbeat: p.Heartbeat | None = None
    heartbeat_time: float = 0.0
    table: p.TableStatus | None = None
    traffic: p.Traffic | None = None
    errors: p.Errors | None = None
    transfers: list[tuple[float, p.TransferStatus]] = field(default_factory=list)
    faults: list[tuple[float, p.Fault]] = field(default_factory=list)


@dataclass(frozen=True)
class Sample:
    time: float  # seconds since the world's epoch
    node: int
    sample: p.DiagnosticSample


class Observer(can.Listener):
    """A python-can listener; thread-safe readers below."""

    def __init__(self, world: w.World) -> None:
        self.world = world
        self._lock = threading.Lock()
        self.nodes: dict[int, NodeView] = defaultdict(NodeView)
        self.malformed: list[str] = []
        self.frames = 0
        self.max_lag = 0.0  # s: how far behind the bus this listener fell, at worst

    def on_message_received(self, message: can.Message) -> None:
        if message.is_error_frame or message.is_remote_frame:
            return
        data = bytes(message.data)
        lag = time.time() - message.timestamp
        with self._lock:
            self.frames += 1
            self.max_lag = max(self.max_lag, lag)
        self.world.on_bus_time(message.timestamp)
        if not message.is_extended_id:
            if message.arbitration_id in (w.ARM_TARGET_ID, w.GAZE_TARGET_ID, w.HAND_COMMAND_ID):
                self.world.on_delivery(message.arbitration_id, data, message.timestamp)
            return
        ident = p.FrameId.decode(message.arbitration_id, True)
        if ident is None or ident.service not in p.DECODERS:
            return
        try:
            decoded = p.DECODERS[ident.service](data)
        except p.MalformedFrame as error:
            with self._lock:
                self.malformed.append(f"node {ident.source}: {error}")
            return
        at = message.timestamp - self.world.epoch
        with self._lock:
            view = self.nodes[ident.source]
            if isinstance(decoded, p.Heartbeat):
                view.heartbeat, view.heartbeat_time = decoded, at
            elif isinstance(decoded, p.TableStatus):
                view.table = decoded
            elif isinstance(decoded, p.Traffic):
                view.traffic = decoded
            elif isinstance(decoded, p.Errors):
                view.errors = decoded
            elif isinstance(decoded, p.TransferStatus):
                view.transfers.append((at, decoded))
            elif isinstance(decoded, p.Fault):
                view.faults.append((at, decoded))

    def node(self, node_id: int) -> NodeView:
        with self._lock:
            view = self.nodes[node_id]
            return NodeView(
                view.heartbeat,
                view.heartbeat_time,
                view.table,
                view.traffic,
                view.errors,
                list(view.transfers),
                list(view.faults),
            )


# The harness's own socket hears only what it acts on: the gateways' frames and the nodes' status
# frames. The diagnostic stream (most of the traffic) goes to the log only, and is read from there.
OBSERVED_SERVICES = (p.FAULT, p.HEARTBEAT, p.TABLE_STATUS, p.TRAFFIC, p.ERRORS, p.TRANSFER_STATUS)
FILTERS = [{"can_id": w.ARM_TARGET_ID & ~0x3, "can_mask": 0x7FC, "extended": False}] + [
    {"can_id": p.PROTOCOL_VALUE | service << 16, "can_mask": p.PROTOCOL_MASK | 0xFF << 16,
     "extended": True}
    for service in OBSERVED_SERVICES
]


class Listening:
    """The harness's socket: the observer on python-can's Notifier thread, and a way to send."""

    def __init__(self, iface: str, observer: Observer) -> None:
        # CAN FD frames too (CAN_RAW_FD_FRAMES): on a CAN FD bus a gateway re-publishes a CAN FD
        # topic's frame as CAN FD, which a classic socket would never see. Classic frames come
        # as before, on either kind of interface.
        self.bus = can.Bus(interface="socketcan", channel=iface, can_filters=FILTERS, fd=True)
        # The default buffer (~270 frames): in a flood, this thread (slower than the bus under
        # emulation) loses some of the re-publications and status frames that pass its filters,
        # rather than falling seconds behind the bus, which the closed loop could not afford.
        # Whatever must not be missed (faults, counts) is read from the recorder's log.
        self.notifier = can.Notifier(self.bus, [observer], timeout=0.1)

    def send(self, arbitration_id: int, data: bytes, extended: bool = True) -> None:
        self.bus.send(can.Message(arbitration_id=arbitration_id, is_extended_id=extended, data=data))

    def close(self) -> None:
        self.notifier.stop()
        self.bus.shutdown()


class Recorder:
    """The candump log: can-utils' `candump -L` in a process of its own, every frame on the bus
    with the kernel's receive timestamps, in the format `canplayer` and python-can read.

    A C program, not Python: under software emulation a Python recorder took about a millisecond
    a frame, fell seconds behind a bus carrying a plant's 1 200 frames a second, and then needed
    minutes to drain at the end. The socket's receive buffer is large (`RECORDER_BUFFER`), so
    that a flood waits in the kernel rather than being dropped while candump writes."""

    def __init__(self, iface: str, log_path: Path) -> None:
        candump = shutil.which("candump")
        if candump is None:
            raise RuntimeError("the bus recorder needs candump (Debian: apt-get install can-utils)")
        log_path.parent.mkdir(parents=True, exist_ok=True)
        self.log_path = log_path
        self._log = open(log_path, "wb")
        self.process = subprocess.Popen([candump, "-L", "-r", str(RECORDER_BUFFER), iface],
                                        stdout=self._log, stderr=subprocess.PIPE)
        # Ready once its socket is bound, so that every later frame is recorded: once it waits
        # for frames (a quiet bus), or once it has written one (a busy bus, where it may never be
        # seen waiting: a plant's 800 frames a second beside two busy processes kept it running
        # or runnable at every look for 30 s).
        deadline = time.monotonic() + 30
        while not (_waiting_for_input(self.process.pid) or _last_timestamp(log_path) > 0):
            if self.process.poll() is not None:
                error = self.process.stderr.read().decode(errors="replace").strip()
                self._log.close()
                raise RuntimeError(f"the bus recorder (candump) could not open {iface}: {error}")
            if time.monotonic() > deadline:
                self.close()
                raise RuntimeError(f"the bus recorder (candump) did not start on {iface} in 30 s")
            time.sleep(0.01)

    def close(self) -> None:
        """Stops the recording once candump has written every frame received before the call.

        candump stops at once on SIGINT, whatever its socket still holds: first it is let catch
        up, until the log holds a frame stamped after the call (the bus is busy) or candump has
        been seen waiting for frames, its socket empty, for `IDLE_S` (the bus is quiet; what it
        holds in its output buffer it writes as it exits). Not "the log stopped growing": a
        candump kept off the CPU by the real-time nodes of a flood stops growing its log too,
        and was stopped with 2 109 of the flood's 5 000 frames unread."""
        if self.process.poll() is None:
            until = time.time()
            deadline = time.monotonic() + CATCH_UP_S
            waiting_since = None
            while _last_timestamp(self.log_path) < until:
                if _waiting_for_input(self.process.pid):
                    waiting_since = waiting_since or time.monotonic()
                    if time.monotonic() - waiting_since >= IDLE_S:
                        break
                else:
                    waiting_since = None
                if time.monotonic() > deadline:
                    print(f"pab-hil: the bus recorder was still behind {CATCH_UP_S} s after the "
                          f"run: {self.log_path} may lack its last frames", file=sys.stderr)
                    break
                time.sleep(0.02)
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if not self._log.closed:
            self._log.close()
        if self.process.stderr is not None:
            self.process.stderr.close()


# A CAN frame costs about 1 KiB of a socket's receive buffer: 64 MiB holds a flood of some 60 000
# frames while candump writes.
RECORDER_BUFFER = 64 << 20
# s: how long candump must be seen waiting for frames to count as caught up.
IDLE_S = 0.5
# s: how long it is given to catch up at most.
CATCH_UP_S = 120

# System calls a process waits for frames in, by machine: poll, select, recvmsg, pselect6, ppoll,
# epoll_wait, epoll_pwait (candump waits in select).
_WAIT_SYSCALLS = {
    "x86_64": {7, 23, 47, 270, 271, 232, 281},
    "aarch64": {73, 72, 212, 22},
}.get(platform.machine(), set())


def backlog_drops() -> int | None:
    """Frames the kernel dropped from its receive backlogs since boot, summed over CPUs (the
    second column of /proc/net/softnet_stat); None where there is no such file.

    On vcan every frame written reaches the other sockets through that backlog: a drop there is
    a frame lost on the bus that no node and no socket counts (the writer's write succeeded)."""
    try:
        with open("/proc/net/softnet_stat") as stat:
            return sum(int(line.split()[1], 16) for line in stat if line.strip())
    except (OSError, IndexError, ValueError):
        return None


def _waiting_for_input(pid: int) -> bool:
    """Whether process `pid` sleeps in a system call that waits for input (/proc/PID/syscall:
    its number first, "running" while it runs). On a machine whose numbers are not listed: once
    it sleeps at all (it has no other reason to, once started)."""
    try:
        first = Path(f"/proc/{pid}/syscall").read_text().split(maxsplit=1)[0]
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "S" \
            and (not _WAIT_SYSCALLS or (first.isdigit() and int(first) in _WAIT_SYSCALLS))
    except (OSError, IndexError):
        return False


def _last_timestamp(log_path: Path) -> float:
    """The timestamp of the log's last whole line, 0 if none."""
    with open(log_path, "rb") as f:
        f.seek(0, 2)
        size = f.tell()
        f.seek(max(0, size - 512))
        lines = f.read().split(b"\n")
    for line in reversed(lines[:-1]):  # the part after the last newline may be half written
        if line.startswith(b"(") and b")" in line:
            try:
                return float(line[1:line.index(b")")])
            except ValueError:
                return 0.0
    return 0.0


def samples(log_path: Path, epoch: float) -> list[Sample]:
    """The nodes' diagnostic samples in a candump log, times relative to `epoch`."""
    out = []
    for message in can.CanutilsLogReader(str(log_path)):
        ident = p.FrameId.decode(message.arbitration_id, message.is_extended_id)
        if ident is None or ident.service != p.DIAGNOSTIC:
            continue
        try:
            sample = p.DiagnosticSample.decode(bytes(message.data))
        except p.MalformedFrame:
            continue
        out.append(Sample(message.timestamp - epoch, ident.source, sample))
    return out
