"""The harness's ears: a recorder process writes every frame on the bus to a candump log; the
harness's own socket hears the gateways' re-published frames (passed to the world, which obeys
them) and the nodes' status frames (decoded, for the tests)."""

from __future__ import annotations

import multiprocessing
import socket
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import can

from . import protocol as p
from . import world as w

SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)


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
        self.bus = can.Bus(interface="socketcan", channel=iface, can_filters=FILTERS)
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
    """The candump log, written by a process of its own so that it keeps up whatever the harness
    does: every frame on the bus, with the kernel's receive timestamps."""

    def __init__(self, iface: str, log_path: Path) -> None:
        log_path.parent.mkdir(parents=True, exist_ok=True)
        context = multiprocessing.get_context("fork")
        self._ready = context.Event()
        self._stop = context.Event()
        self.process = context.Process(target=_record, args=(iface, log_path, self._ready, self._stop),
                                       name="recorder", daemon=True)
        self.process.start()
        if not self._ready.wait(30):
            self.process.kill()
            raise RuntimeError(f"the bus recorder could not open {iface}")

    def close(self) -> None:
        self._stop.set()
        # It may be seconds behind after a flood: let it drain the kernel's queue to the file.
        self.process.join(timeout=120)
        if self.process.is_alive():
            self.process.kill()


# A CAN frame costs about 1 KiB of a socket's receive buffer; the default (~200 KiB) overflows in
# a fraction of a second of flood while the recorder (Python) is busy writing.
RECORDER_BUFFER = 64 << 20


def _large_buffer(sock: socket.socket, size: int) -> None:
    try:  # root may exceed net.core.rmem_max; others get what rmem_max allows
        sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, size)
    except OSError:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)


def _record(iface: str, log_path: Path, ready, stop) -> None:
    bus = can.Bus(interface="socketcan", channel=iface)
    _large_buffer(bus.socket, RECORDER_BUFFER)
    # `.log` is candump's -L format: "(1700000000.123456) vcan0 110#0102030405060708 R".
    writer = can.CanutilsLogWriter(str(log_path), channel=iface)
    ready.set()
    try:
        while not stop.is_set():
            message = bus.recv(timeout=0.1)
            if message is not None:
                writer.on_message_received(message)
        # Whatever the kernel still holds for us.
        while (message := bus.recv(timeout=0.05)) is not None:
            writer.on_message_received(message)
    finally:
        writer.stop()
        bus.shutdown()


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
