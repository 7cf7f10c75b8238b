"""A schema server's client over a python-can bus: schemas sent over ISO-TP (can-isotp), their
answers, the server's transitions and state, abort and emergency stop.

    import can
    from pab_client import Client, client_filters, pose_mm

    with can.Bus(interface="socketcan", channel="can0", can_filters=client_filters(5)) as bus, \
            Client(bus, node=5) as arm:
        arm.move_to(pose_mm(-100, -60, 35), speed=20_000)       # µm, µm/s
        arm.move_to_touch((0, 0, -1), contact=3_000)             # direction; mN
        done = arm.grasp()
        print(arm.wait_finished(done.id, timeout=30).event)      # Event.Done()

Units are the board's (µm, µrad, µm/s, mN, ms; see :mod:`pab_client.schema`).

The client reads the bus through a ``can.Notifier`` (its own, or one passed in: python-can lets
one notifier serve a bus), so that the ISO-TP layer and the reports share it; nothing else may
``recv`` on that bus meanwhile. Open the bus with :func:`client_filters`: the node's flow control
must reach the ISO-TP layer within its timeout (1 s), and a bus without filters hands the
notifier every frame of the bus first (on a loaded or emulated machine, a plant's 1 kHz poses
delayed it past that).
"""

from __future__ import annotations

import collections
import queue
import struct
import math
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Deque, Dict, List, Optional, Sequence

import can
import isotp

from . import schema as s
from . import auth
from .protocol import (
    BROADCAST,
    CHALLENGE,
    CHALLENGE_REQUEST,
    FAULT,
    NO_ID,
    PRIORITY,
    RECEIPT,
    STOP_NUMBERS,
    TOOL,
    TRANSFER_OPEN,
    AuthFailure,
    FaultCode,
    FrameId,
    MalformedFrame,
    SchemaAck,
    SchemaChannel,
    SchemaOutcome,
    SchemaSafety,
    SchemaState,
    SchemaTransition,
    SchemaTrigger,
    abort_id,
    client_filters,
    decode_fault,
    decode_report,
    emergency_stop_id,
    frame_id,
    limits_message,
    transfer_ids,
    transfer_message,
)

#: The first and last ids the client gives its schemas (below the server's own, 0xFF00).
FIRST_ID = 1
LAST_ID = 0xFEFF

#: Outcomes that mean "no room yet": retried by :meth:`Client.install_when_room`.
NO_ROOM = (SchemaOutcome.QueueFull, SchemaOutcome.Busy)


class ClientError(Exception):
    """Base of the client's errors."""


class Refused(ClientError):
    """The node refused the schema (or the limits): `outcome` says why, `ack` is its whole
    answer."""

    def __init__(self, ack: SchemaAck, node: int):
        self.ack = ack
        self.outcome = ack.outcome
        self.node = node
        what = "limits" if ack.channel == SchemaChannel.Limits else f"schema {ack.id:#06x}"
        super().__init__(
            f"node {node} refused {what}: {ack.outcome.name} ({ack.outcome.description})"
        )


class Timeout(ClientError):
    """No answer in time (no flow control, no SchemaAck, no transition or state)."""


class Denied(ClientError):
    """A keyed node did not answer because it refused tagged messages meanwhile (its
    Unauthenticated faults): `refused` of them, and `flooded` when some were beyond the checks it
    makes in a second (200), which a participant sending bad tags causes. Retrying helps only
    once the flood stops; `candump` shows the source of the tagged frames."""

    def __init__(self, node: int, refused: int, flooded: bool, what: str):
        self.node = node
        self.refused = refused
        self.flooded = flooded
        if flooded:
            why = (f"the node refused {refused} tags, more than it checks in a second: someone "
                   "is flooding it with bad tags (`candump` shows the source of the tagged frames)")
        else:
            why = (f"the node refused {refused} tags as wrong: a key that is not the node's, or "
                   "someone sending it bad tags")
        super().__init__(f"node {node}: {what}: {why}")


class InvalidArgument(ClientError, ValueError):
    """An argument the client refuses before it sends anything: a timeout that is not a
    number of seconds in [0, MAX_SECONDS], a node or stop number out of range, ... (a
    :class:`ValueError` too, so ``except ValueError`` still catches it)."""


#: The longest timeout the client takes, in seconds (about 11.6 days, the network file's
#: longest time): a longer one is a unit mistake (milliseconds given as seconds).
MAX_SECONDS = 1_000_000.0


def _seconds(name: str, value: Any, optional: bool = False) -> Optional[float]:
    """`value` as a timeout in seconds, or :class:`InvalidArgument`. ``None`` passes where the
    method waits without bound. NaN and infinities are refused: ``wait(nan)`` never returns in
    ``threading.Condition``, and a deadline of ``inf`` is no deadline."""
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidArgument(f"{name} = {value!r}: a number of seconds")
    if not math.isfinite(value) or not 0 <= value <= MAX_SECONDS:
        raise InvalidArgument(f"{name} = {value!r}: seconds, 0 to {MAX_SECONDS:g}")
    return float(value)


@dataclass(frozen=True)
class Ended:
    """How a schema of the client's ended (:meth:`Client.wait_finished`)."""

    #: The schema's id.
    id: int
    #: The node's SchemaTransition that ended it.
    transition: SchemaTransition
    #: The reaction of the schema that fired (trigger Reaction), when the client sent it.
    reaction: Optional[s.Reaction]

    @property
    def trigger(self) -> SchemaTrigger:
        """Reaction (the schema's own event), HighPriority (replaced), Abort or Safety."""
        return self.transition.trigger

    @property
    def event(self) -> Optional[s.Event]:
        """The event that ended it, for trigger Reaction (``Done()``, ``Above(Contact(), ..)``)."""
        return None if self.reaction is None else self.reaction.event

    @property
    def safety(self) -> Optional[SchemaSafety]:
        """The safety event that ended it, for trigger Safety."""
        return self.transition.safety

    @property
    def reaction_index(self) -> Optional[int]:
        """The index of the reaction that fired, for trigger Reaction."""
        return self.transition.detail if self.trigger == SchemaTrigger.Reaction else None

    @property
    def next(self) -> int:
        """The id of the schema installed after it (0xFF00 the wait for the queue, 0xFF01 the
        wait for the high-priority channel, 0xFF10 + cause a safety recovery)."""
        return self.transition.installed


class Client:
    """A client of the schema server on `node`, over `bus` (a python-can bus with 29-bit
    frames), speaking as `source` (0: the tool).

    Every method that sends a schema (or, :meth:`set_limits`, the safety bounds) returns the
    node's :class:`SchemaAck` when it accepted it, raises :class:`Refused` when it did not,
    :class:`Timeout` when it did not answer.
    """

    def __init__(
        self,
        bus: can.BusABC,
        node: int,
        source: int = TOOL,
        *,
        key: Optional[bytes] = None,
        notifier: Optional[can.Notifier] = None,
        first_id: int = FIRST_ID,
    ) -> None:
        if not 1 <= node <= 127:
            raise InvalidArgument(f"node {node}: nodes are 1..=127")
        if key is not None and (len(key) != 16 or source != TOOL):
            raise InvalidArgument("a key is 16 bytes (pab_client.auth.read_key), and a node with a key "
                             "takes schemas from the tool (source 0) only")
        if not 0 <= source <= 127:
            raise InvalidArgument(f"source {source}: 0 (the tool) or a node, 1..=127")
        if not FIRST_ID <= first_id <= LAST_ID:
            raise InvalidArgument(f"first_id {first_id}: ids are {FIRST_ID}..={LAST_ID:#06x}")
        self.bus = bus
        self.node = node
        self.source = source
        #: The node's key: every schema goes as the key holder's (a challenge, a TransferOpen,
        #: the message and its MAC) and its SchemaAck counts only with a Receipt that verifies.
        self.key = key
        self._challenges: List[int] = []
        self._receipts: List[bytes] = []
        # The TransferOpen to send right before the transfer's first frame (see _isotp_tx).
        self._pending_open: Optional[can.Message] = None
        self.txid, self.rxid = transfer_ids(node, source)
        #: Report frames of the node that broke their layout (ignored).
        self.malformed = 0
        # The node's refusals of tagged messages since the current transfer began (its
        # Unauthenticated faults' counts), and whether its checks for a second ran out.
        self._refused = 0
        self._flooded = False
        self._next_id = first_id
        self._id_lock = threading.Lock()
        self._transfer_lock = threading.Lock()
        self._cond = threading.Condition()
        self._acks: List[SchemaAck] = []
        self._started: Dict[int, SchemaTransition] = {}
        self._ended: Dict[int, SchemaTransition] = {}
        self._sent: Dict[int, s.Schema] = {}
        self._transitions: Deque[SchemaTransition] = collections.deque(maxlen=1024)
        self._state: Optional[SchemaState] = None
        self._state_seq = 0
        self._report_seq = 0
        self._queued: Optional[int] = None
        # The latest stop number the node reported (SchemaState, SchemaAck), and the one the
        # application acknowledged, which high-priority schemas name.
        self._stop_seen: Optional[int] = None
        self._stop_acknowledged: Optional[int] = None
        self._flow_control: "queue.Queue[isotp.CanMessage]" = queue.Queue()
        self._isotp_errors: List[Exception] = []
        self._isotp = isotp.TransportLayer(
            rxfn=self._isotp_rx,
            txfn=self._isotp_tx,
            address=isotp.Address(
                isotp.AddressingMode.Normal_29bits, txid=self.txid, rxid=self.rxid
            ),
            error_handler=self._isotp_error,
            params={
                # docs/can-protocol.md, "Table transfer": classic CAN, every frame 8 bytes,
                # padded with 0xCC; the node's flow control decides block size and STmin.
                "tx_data_length": 8,
                "tx_data_min_length": 8,
                "tx_padding": 0xCC,
                "can_fd": False,
                "blocking_send": True,
            },
            read_timeout=0.01,
        )
        self._isotp.start()
        self._own_notifier = notifier is None
        self._notifier = notifier or can.Notifier(bus, [], timeout=0.05)
        self._notifier.add_listener(self._on_message)
        self._closed = False

    # -- life ---------------------------------------------------------------------------------

    def close(self) -> None:
        """Stops the ISO-TP layer and the notifier (if the client made it). The bus stays open."""
        if self._closed:
            return
        self._closed = True
        try:
            self._notifier.remove_listener(self._on_message)
        except ValueError:
            pass
        if self._own_notifier:
            self._notifier.stop()
        self._isotp.stop()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- the bus ------------------------------------------------------------------------------

    def _isotp_rx(self, timeout: float) -> Optional[isotp.CanMessage]:
        try:
            return self._flow_control.get(timeout=timeout)
        except queue.Empty:
            return None

    def _isotp_tx(self, msg: isotp.CanMessage) -> None:
        # The open goes out from the ISO-TP layer's thread, just before the first frame: sent
        # from the caller's thread, it could reach the node after the first frame (each thread's
        # frames are queued on the CPU it runs on; seen under software emulation), and the node
        # drops a first frame that no open announced.
        pending, self._pending_open = self._pending_open, None
        if pending is not None:
            self.bus.send(pending)
        self.bus.send(
            can.Message(
                arbitration_id=msg.arbitration_id,
                data=bytes(msg.data),
                is_extended_id=True,
            )
        )

    def _isotp_error(self, error: Exception) -> None:
        self._isotp_errors.append(error)

    def _on_message(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_remote_frame or not msg.is_extended_id:
            return
        if msg.arbitration_id == self.rxid:
            # The node's flow control for our transfers.
            self._flow_control.put(
                isotp.CanMessage(
                    arbitration_id=msg.arbitration_id, data=bytes(msg.data), extended_id=True
                )
            )
            return
        fid = FrameId.decode(msg.arbitration_id, True)
        if fid is not None and fid.service == FAULT and fid.source == self.node:
            try:
                decoded_fault = decode_fault(msg.arbitration_id, True, bytes(msg.data))
            except MalformedFrame:
                self.malformed += 1
                return
            fault = decoded_fault[1] if decoded_fault is not None else None
            if fault is not None and fault.code == FaultCode.Unauthenticated:
                with self._cond:
                    self._refused += fault.count
                    self._flooded |= fault.auth_failure == AuthFailure.RateLimited
                    self._cond.notify_all()
            return
        if (fid is not None and fid.service in (CHALLENGE, RECEIPT) and fid.source == self.node
                and fid.destination == self.source and len(msg.data) == 8
                and fid.priority == PRIORITY[fid.service]):
            with self._cond:
                if fid.service == CHALLENGE:
                    data = bytes(msg.data)
                    self._challenges.append((int.from_bytes(data[:auth.NODE_NONCE_LEN], "little"),
                                             data[auth.NODE_NONCE_LEN:]))
                else:
                    self._receipts.append(bytes(msg.data))
                self._cond.notify_all()
            return
        try:
            decoded = decode_report(msg.arbitration_id, True, bytes(msg.data))
        except MalformedFrame:
            self.malformed += 1
            return
        if decoded is None:
            return
        fid, report = decoded
        if fid.source != self.node:
            return
        with self._cond:
            if isinstance(report, SchemaAck):
                if fid.destination != self.source:
                    return
                self._acks.append(report)
                self._stop_seen = report.stop
            elif isinstance(report, SchemaTransition):
                self._ended[report.ended] = report
                self._started[report.installed] = report
                self._transitions.append(report)
                self._queued = report.queued
            else:
                self._state = report
                self._state_seq += 1
                self._queued = report.queued
                self._stop_seen = report.stop
            if not isinstance(report, SchemaAck):
                # A report of the queue's length (install_when_room waits for one).
                self._report_seq += 1
            self._cond.notify_all()

    # -- schemas ------------------------------------------------------------------------------

    def next_id(self) -> int:
        """The id the next convenience call gives its schema: 1, 2, ... 0xFEFF, then 1 again."""
        with self._id_lock:
            sid = self._next_id
            self._next_id = FIRST_ID if sid >= LAST_ID else sid + 1
            return sid

    # -- stops --------------------------------------------------------------------------------

    @property
    def stop_number(self) -> Optional[int]:
        """The node's latest stop number (its stops so far, emergency stops, aborts and safety
        events, modulo 64), from its SchemaState and SchemaAck; None before either came."""
        with self._cond:
            return self._stop_seen

    def acknowledge_stop(self, stop: Optional[int] = None, timeout: float = 1.0) -> int:
        """Acknowledges the node's latest stop, or stop number `stop`: the high-priority schemas
        sent from now on name it, and the first one the node takes ends that stop.

        Call it deliberately, once the application knows why the robot stopped: a high-priority
        schema names the stop it acknowledges, and the node refuses one that names an older
        stop (``StopNotAcknowledged``), so a schema sent before an operator's stop never undoes
        it. Without `stop`, the latest stop number the node reported, waiting up to `timeout` s
        for a SchemaState if none came yet (:class:`Timeout`). Returns the number."""
        timeout = _seconds("timeout", timeout)
        if stop is None:
            with self._cond:
                if self._stop_seen is None and not self._cond.wait_for(
                    lambda: self._stop_seen is not None, timeout
                ):
                    raise Timeout(f"node {self.node}: no SchemaState in {timeout} s")
                stop = self._stop_seen
        if not 0 <= stop < STOP_NUMBERS:
            raise InvalidArgument(f"stop number {stop}: 0..{STOP_NUMBERS - 1}")
        with self._cond:
            self._stop_acknowledged = stop
        return stop

    # -- schemas (continued) --------------------------------------------------------------------

    def install(
        self, schema: s.Schema, high_priority: bool = False, timeout: float = 1.0
    ) -> SchemaAck:
        """Sends `schema` to the node, on its queue or (`high_priority`) on the high-priority
        channel (installed at the node's next tick, replacing the running schema and ending a
        stop), and waits at most `timeout` s for the node's SchemaAck. A high-priority schema
        names the stop the application acknowledged (:meth:`acknowledge_stop`, needed once
        before the first): the node refuses it if a stop came since (``StopNotAcknowledged``).

        Returns the SchemaAck when the node accepted it; raises :class:`Refused` (with the
        node's outcome) when it did not, :class:`Timeout` when the node did not answer the
        transfer's flow control or sent no SchemaAck in time.
        """
        stop = 0
        if high_priority:
            with self._cond:
                acknowledged = self._stop_acknowledged
            if acknowledged is None:
                raise ClientError(
                    f"node {self.node}: a high-priority schema names the stop it acknowledges: "
                    "call acknowledge_stop() first"
                )
            stop = acknowledged
        message = transfer_message(schema.encode(), high_priority, stop)

        def forget() -> None:
            # Under the condition: the id's earlier start and end are another schema's.
            self._started.pop(schema.id, None)
            self._ended.pop(schema.id, None)
            self._sent[schema.id] = schema

        return self._transfer(message, schema.id, f"schema {schema.id:#06x}", timeout, forget)

    def set_limits(self, limits: s.Limits, timeout: float = 1.0) -> SchemaAck:
        """Sets the safety bounds the node runs with (:class:`pab_client.schema.Limits`), from
        its next tick: a SchemaTransfer message on the limits channel (channel byte 2), on a
        node with a key opened, MAC'd and confirmed by a Receipt as a schema is. Each bound must
        be within the table's: tighter, or back up to the table's, never looser.

        Returns the SchemaAck (channel ``Limits``, id 0xFFFF) when the node took them; raises
        :class:`Refused` when it did not (``Looser``: looser than the table's somewhere, other
        joints than the table's, or inconsistent; ``NoServer``, ``Malformed``, ...),
        :class:`Timeout` as :meth:`install` does."""
        if not isinstance(limits, s.Limits):
            raise TypeError(f"set_limits takes a pab_client.schema.Limits, not {limits!r}")
        return self._transfer(limits_message(limits.encode()), NO_ID, "limits", timeout)

    def _transfer(
        self,
        message: bytes,
        sid: int,
        what: str,
        timeout: float,
        before: Optional[Callable[[], None]] = None,
    ) -> SchemaAck:
        """Sends one SchemaTransfer message (with a key: after a challenge and its open, with
        its MAC) and waits for its SchemaAck, the one naming `sid` (or NO_ID), and with a key
        its Receipt. `before` runs under the reports' lock before anything is sent."""
        timeout = _seconds("timeout", timeout)
        deadline = time.monotonic() + timeout
        with self._transfer_lock:
            with self._cond:
                self._acks.clear()
                self._receipts.clear()
                self._refused, self._flooded = 0, False
                if before is not None:
                    before()
            while not self._flow_control.empty():
                self._flow_control.get_nowait()
            del self._isotp_errors[:]
            nonce = None
            if self.key is not None:
                nonce = self._challenge(deadline)
                message = self._open(message, nonce)
            failure: Optional[Exception] = None
            try:
                self._isotp.send(message, send_timeout=max(0.0, deadline - time.monotonic()))
            except isotp.BlockingSendFailure as e:
                failure = e
                self._isotp.stop_sending()
            finally:
                self._pending_open = None
            # A transfer the node stopped (flow control "overflow") still has its answer.
            ack_deadline = deadline if failure is None else max(deadline, time.monotonic() + 0.1)
            ack = self._wait_ack(sid, ack_deadline)
            if ack is not None and nonce is not None:
                self._confirm(ack, nonce, ack_deadline, what)
        if ack is None and self._refused:
            raise Denied(self.node, self._refused, self._flooded, f"{what}: no SchemaAck")
        what = f"node {self.node}: {what}"
        if ack is None:
            if failure is not None:
                errors = [str(e) or type(e).__name__ for e in self._isotp_errors]
                why = "; ".join(errors) or str(failure)
                raise Timeout(f"{what}: the transfer failed ({why})")
            raise Timeout(f"{what}: no SchemaAck in {timeout} s")
        if ack.outcome != SchemaOutcome.Accepted:
            raise Refused(ack, self.node)
        return ack

    def _challenge(self, deadline: float) -> int:
        """Asks the node for a challenge with a new tool nonce; the exchange nonce of the first
        Challenge bound to this request (:class:`Timeout` without one). A Challenge that does not
        answer this request (made up by someone else, or answering another tool's) is skipped
        and counted in the timeout's message."""
        tool_nonce = auth.new_tool_nonce()
        with self._cond:
            self._challenges.clear()
        self.bus.send(can.Message(arbitration_id=frame_id(CHALLENGE_REQUEST, self.source, self.node),
                                  data=struct.pack("<Q", tool_nonce), is_extended_id=True))
        unbound = 0
        with self._cond:
            while True:
                if not self._cond.wait_for(lambda: self._challenges,
                                           max(0.0, deadline - time.monotonic())):
                    if self._refused:
                        raise Denied(self.node, self._refused, self._flooded, "no Challenge")
                    if unbound:
                        raise Timeout(
                            f"node {self.node}: no Challenge answering this request, and "
                            f"{unbound} that did not verify for it: a key that is not the "
                            "node's, another tool configuring it, or a participant making them up")
                    raise Timeout(f"node {self.node}: no Challenge: is it on the bus, and does it "
                                  "have a key? (a node without one sends none)")
                node_nonce, binding = self._challenges.pop(0)
                nonce, expected = auth.exchange(self.key, self.node, tool_nonce, node_nonce)
                if binding == expected:
                    return nonce
                unbound += 1

    def _open(self, message: bytes, nonce: int) -> bytes:
        """The TransferOpen for `message`, sent before its first frame; returns the message
        with its MAC, as it is sent."""
        key = self.key
        message = message + auth.image_mac(key, self.node, nonce, auth.OPEN_SCHEMA, message)
        payload = struct.pack("<HB", len(message), auth.OPEN_SCHEMA) + auth.open_tag(
            key, self.node, nonce, len(message), auth.OPEN_SCHEMA)
        self._pending_open = can.Message(
            arbitration_id=frame_id(TRANSFER_OPEN, self.source, self.node), data=payload,
            is_extended_id=True)
        return message

    def _confirm(self, ack: SchemaAck, nonce: int, deadline: float, what: str) -> None:
        """The Receipt for `ack` (which may have come first: its identifier ranks above
        SchemaAck's), verified under the key; :class:`ClientError` when none comes or it does
        not verify (a forged answer, or another key)."""
        expected = auth.receipt_tag(self.key, self.node, nonce, ack.encode(), 0, False)
        with self._cond:
            if not self._cond.wait_for(lambda: self._receipts,
                                       max(0.05, deadline - time.monotonic())):
                raise ClientError(f"node {self.node}: no Receipt for {what}")
            tag = self._receipts.pop(0)
        if tag != expected:
            raise ClientError(f"node {self.node}: the Receipt for {what} does not verify "
                              "(another key, or a forged answer)")

    def _wait_ack(self, sid: int, deadline: float) -> Optional[SchemaAck]:
        def ours() -> Optional[SchemaAck]:
            for i, ack in enumerate(self._acks):
                if ack.id in (sid, NO_ID):
                    return self._acks.pop(i)
            return None

        with self._cond:
            while True:
                ack = ours()
                if ack is not None:
                    return ack
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(remaining)

    def install_when_room(
        self,
        schema: s.Schema,
        high_priority: bool = False,
        timeout: float = 10.0,
        ack_timeout: float = 1.0,
        retry_s: float = 0.1,
    ) -> SchemaAck:
        """:meth:`install`, retried while the node answers ``QueueFull`` (its 8-deep queue is
        full) or ``Busy`` (a high-priority schema waits for its tick): after such a refusal it
        waits for a transition or state from the node showing room in the queue, at most
        `retry_s` s, and tries again. Each try waits `ack_timeout` s for its answer; no try
        starts after `timeout` s. Raises :class:`Timeout` (its ``__cause__`` the last
        :class:`Refused`) when there was no room by then, :class:`Refused` for any other
        refusal."""
        timeout = _seconds("timeout", timeout)
        ack_timeout = _seconds("ack_timeout", ack_timeout)
        retry_s = _seconds("retry_s", retry_s)
        deadline = time.monotonic() + timeout
        while True:
            with self._cond:
                seq = self._report_seq
            try:
                return self.install(schema, high_priority, timeout=ack_timeout)
            except Refused as refused:
                if refused.outcome not in NO_ROOM:
                    raise
                last = refused
            remaining = deadline - time.monotonic()
            with self._cond:
                room = remaining > 0 and self._cond.wait_for(
                    lambda: self._report_seq > seq
                    and (self._queued is None or self._queued < s.QUEUE_DEPTH),
                    min(retry_s, remaining),
                )
            if not room and time.monotonic() >= deadline:
                raise Timeout(
                    f"node {self.node}: no room for schema {schema.id:#06x} in {timeout} s "
                    f"({last.outcome.name})"
                ) from last

    def _build_and_install(
        self,
        make: Callable[[int], s.Schema],
        high_priority: bool,
        timeout: float,
        wait_for_room: Optional[float],
    ) -> SchemaAck:
        # Checked before the schema takes an id: a refused argument leaves the ids as they were.
        _seconds("timeout", timeout)
        _seconds("wait_for_room", wait_for_room, optional=True)
        schema = make(self.next_id())
        if wait_for_room is None:
            return self.install(schema, high_priority, timeout)
        return self.install_when_room(
            schema, high_priority, timeout=wait_for_room, ack_timeout=timeout
        )

    # The paper's calls: each builds its schema (pab_core::schema::build's reactions, the network
    # file's defaults) with the next id and installs it. `high_priority`, `timeout` as for
    # install; `wait_for_room` (s) retries a full queue as install_when_room does.

    def move_to(
        self,
        goal: Sequence[int],
        speed: int = 50_000,
        *,
        watchdog_ms: int = 0,
        high_priority: bool = False,
        timeout: float = 1.0,
        wait_for_room: Optional[float] = None,
    ) -> SchemaAck:
        """The attractor to `goal` (µm, µrad) at `speed` µm/s:
        :func:`pab_client.schema.move_to`."""
        return self._build_and_install(
            lambda sid: s.move_to(sid, goal, speed, watchdog_ms=watchdog_ms),
            high_priority,
            timeout,
            wait_for_room,
        )

    def move_to_touch(
        self,
        direction: Sequence[int],
        speed: int = 5_000,
        contact: int = 3_000,
        distance: int = 50_000,
        *,
        watchdog_ms: int = 0,
        high_priority: bool = False,
        timeout: float = 1.0,
        wait_for_room: Optional[float] = None,
    ) -> SchemaAck:
        """Along `direction` at `speed` µm/s until `contact` mN, at most `distance` µm:
        :func:`pab_client.schema.move_to_touch`."""
        return self._build_and_install(
            lambda sid: s.move_to_touch(
                sid, direction, speed, contact, distance, watchdog_ms=watchdog_ms
            ),
            high_priority,
            timeout,
            wait_for_room,
        )

    def grasp(
        self,
        settle_ms: int = 200,
        *,
        watchdog_ms: int = 0,
        high_priority: bool = False,
        timeout: float = 1.0,
        wait_for_room: Optional[float] = None,
    ) -> SchemaAck:
        """Close the gripper, `settle_ms` ms: :func:`pab_client.schema.grasp`."""
        return self._build_and_install(
            lambda sid: s.grasp(sid, settle_ms, watchdog_ms=watchdog_ms),
            high_priority,
            timeout,
            wait_for_room,
        )

    def release(
        self,
        settle_ms: int = 200,
        *,
        watchdog_ms: int = 0,
        high_priority: bool = False,
        timeout: float = 1.0,
        wait_for_room: Optional[float] = None,
    ) -> SchemaAck:
        """Open the gripper, `settle_ms` ms: :func:`pab_client.schema.release`."""
        return self._build_and_install(
            lambda sid: s.release(sid, settle_ms, watchdog_ms=watchdog_ms),
            high_priority,
            timeout,
            wait_for_room,
        )

    def blind_search(
        self,
        preload: int = 2_000,
        pitch: int = 80,
        speed: int = 2_000,
        radius: int = 1_000,
        wobble: int = 20_000,
        wobble_ms: int = 500,
        depth: int = 1_000,
        *,
        watchdog_ms: int = 0,
        high_priority: bool = False,
        timeout: float = 1.0,
        wait_for_room: Optional[float] = None,
    ) -> SchemaAck:
        """The spiral search under preload until the part drops `depth` µm:
        :func:`pab_client.schema.blind_search` (µm, µm/s, µrad, ms)."""
        return self._build_and_install(
            lambda sid: s.blind_search(
                sid, preload, pitch, speed, radius, wobble, wobble_ms, depth, watchdog_ms=watchdog_ms
            ),
            high_priority,
            timeout,
            wait_for_room,
        )

    def idle(
        self,
        ms: int = 0,
        *,
        watchdog_ms: int = 0,
        high_priority: bool = False,
        timeout: float = 1.0,
        wait_for_room: Optional[float] = None,
    ) -> SchemaAck:
        """Hold the command `ms` ms (0: until aborted or replaced):
        :func:`pab_client.schema.idle`."""
        return self._build_and_install(
            lambda sid: s.idle(sid, ms, watchdog_ms=watchdog_ms),
            high_priority,
            timeout,
            wait_for_room,
        )

    def open_gripper(self, **kwargs: Any) -> SchemaAck:
        """Open the gripper at once (the network file's ``open()``)."""
        return self._atomic(s.open_gripper, **kwargs)

    def close_gripper(self, **kwargs: Any) -> SchemaAck:
        """Close the gripper at once (the network file's ``close()``)."""
        return self._atomic(s.close_gripper, **kwargs)

    def relieve(self, **kwargs: Any) -> SchemaAck:
        """The attractor to the measured pose: every force relieved."""
        return self._atomic(s.relieve, **kwargs)

    def set_impedance(self, stiffness: int = 2_000, damping: int = 100, **kwargs: Any) -> SchemaAck:
        """The drive's stiffness (N/m) and damping (N·s/m)."""
        return self._atomic(s.set_impedance, stiffness, damping, **kwargs)

    def _atomic(
        self,
        build: Any,
        *args: Any,
        watchdog_ms: int = 0,
        high_priority: bool = False,
        timeout: float = 1.0,
        wait_for_room: Optional[float] = None,
    ) -> SchemaAck:
        return self._build_and_install(
            lambda sid: build(sid, *args, watchdog_ms=watchdog_ms),
            high_priority,
            timeout,
            wait_for_room,
        )

    # -- stopping -----------------------------------------------------------------------------

    def abort(self, broadcast: bool = False) -> None:
        """SchemaAbort to the node (or every node): it abandons the running schema and waits on
        the high-priority channel. Never refused."""
        self._send_empty(abort_id(BROADCAST if broadcast else self.node, self.source))

    def estop(self, broadcast: bool = False) -> None:
        """EmergencyStop to the node (or every node): it halts within one loop period (the
        attractor to the measured pose) and waits on the high-priority channel, its queue kept
        but not run. Never refused."""
        self._send_empty(emergency_stop_id(BROADCAST if broadcast else self.node, self.source))

    def _send_empty(self, arbitration_id: int) -> None:
        # No payload: a padded stop or abort is malformed.
        self.bus.send(can.Message(arbitration_id=arbitration_id, data=b"", is_extended_id=True))

    # -- reports ------------------------------------------------------------------------------

    def status(self, timeout: Optional[float] = None) -> Optional[SchemaState]:
        """The node's latest SchemaState (None before the first). With a `timeout`, waits for
        the next one received after the call instead (:class:`Timeout` if none comes)."""
        timeout = _seconds("timeout", timeout, optional=True)
        with self._cond:
            if timeout is None:
                return self._state
            seq = self._state_seq
            if not self._cond.wait_for(lambda: self._state_seq > seq, timeout):
                raise Timeout(f"node {self.node}: no SchemaState in {timeout} s")
            return self._state

    @property
    def transitions(self) -> List[SchemaTransition]:
        """The node's transitions received so far (the latest 1024), oldest first."""
        with self._cond:
            return list(self._transitions)

    def wait_started(self, sid: int, timeout: Optional[float] = None) -> SchemaTransition:
        """Waits until schema `sid` is installed (it appears as a transition's `installed`);
        returns that transition. Counts transitions since its install (or since the client
        started, for a schema it did not send)."""
        timeout = _seconds("timeout", timeout, optional=True)
        with self._cond:
            if not self._cond.wait_for(lambda: sid in self._started, timeout):
                raise Timeout(f"node {self.node}: schema {sid:#06x} not started in {timeout} s")
            return self._started[sid]

    def wait_finished(self, sid: int, timeout: Optional[float] = None) -> Ended:
        """Waits until schema `sid` ends (it appears as a transition's `ended`) and says how: its
        own reaction (which one, and its event), the high-priority channel, an abort or a safety
        event. A schema still in the queue when the server stops never ends: use a timeout."""
        timeout = _seconds("timeout", timeout, optional=True)
        with self._cond:
            if not self._cond.wait_for(lambda: sid in self._ended, timeout):
                raise Timeout(f"node {self.node}: schema {sid:#06x} not finished in {timeout} s")
            t = self._ended[sid]
            sent = self._sent.get(sid)
        reaction = None
        if t.trigger == SchemaTrigger.Reaction and sent is not None:
            if t.detail < len(sent.reactions):
                reaction = sent.reactions[t.detail]
        return Ended(sid, t, reaction)


__all__ = [
    "Client",
    "client_filters",
    "ClientError",
    "InvalidArgument",
    "MAX_SECONDS",
    "Refused",
    "Timeout",
    "Ended",
    "FIRST_ID",
    "LAST_ID",
    "NO_ROOM",
]
