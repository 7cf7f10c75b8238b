"""pab_client.Client on python-can's virtual bus, against a scripted node: a thread that receives
the client's ISO-TP frames itself (an implementation independent of can-isotp's: first frame,
flow control every block, consecutive frames in sequence, padding), answers SchemaAck as
firmware/app/src/schema.rs does, and sends the transitions and states a test asks for."""

import itertools
import math
import threading
import time
from typing import Callable, List, Optional, Tuple

import can
import pytest

from pab_client import (
    MAX_SECONDS,
    Client,
    ClientError,
    Denied,
    InvalidArgument,
    Refused,
    Timeout,
    auth,
    client_filters,
    schema as s,
)
from pab_client import protocol as p
from pab_client.protocol import (
    SchemaAck,
    SchemaChannel,
    SchemaOrigin,
    SchemaOutcome,
    SchemaSafety,
    SchemaState,
    SchemaTransition,
    SchemaTrigger,
)

NODE = 5
_channels = itertools.count()

Answer = Callable[[int, Optional[s.Schema]], Tuple[SchemaOutcome, int]]


class FakeNode(threading.Thread):
    """Node `node`'s schema server, as far as the bus shows it."""

    def __init__(self, channel: str, node: int = NODE, block_size: int = 8):
        super().__init__(daemon=True)
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.node = node
        self.block_size = block_size
        #: (channel, schema) -> (outcome, queued); accepts everything by default.
        self.answer: Answer = lambda channel, schema: (SchemaOutcome.Accepted, 1)
        #: Complete SchemaTransfer messages received.
        self.messages: List[bytes] = []
        #: Every SchemaTransfer frame from the client.
        self.frames: List[bytes] = []
        #: Every other frame of ours from the client: (id, data).
        self.others: List[Tuple[int, bytes]] = []
        self.stop_number = 0  # the server's stops so far, modulo 64
        #: The table's limits, which limits on the limits channel must be within; the limits
        #: in force (the table's, until a client sets others).
        self.table_limits = s.Limits()
        self.limits = self.table_limits
        #: A node with this key: challenges, opens and MACs as docs/can-protocol.md says, and a
        #: Receipt before each SchemaAck (its identifier ranks first, as on a real node).
        self.key: Optional[bytes] = None
        self.node_nonce = 0x1234_5678_0000
        self.nonce = 0  # the exchange nonce of the last challenge
        #: Challenges made up (not bound to the request) sent before each genuine one.
        self.unbound_challenges = 0
        #: Whether the node answers requests at all (False: only the made-up challenges).
        self.genuine_challenges = True
        #: A flood of bad tags from someone else: (refused, why) faults instead of challenges.
        self.refusing: Optional[Tuple[int, p.AuthFailure]] = None
        self.opened: Optional[int] = None  # the nonce of the open the next transfer consumes
        self.forge_receipt = False
        self.silent = False  # no flow control
        self.no_ack = False
        self.overflow = False  # flow control "overflow", then TooLong
        self.errors: List[str] = []
        self._halt = threading.Event()
        self.txid, self.rxid = p.transfer_ids(node)  # client -> node, node -> client

    def run(self) -> None:
        buf = bytearray()
        expected = 0
        sn = 0
        in_block = 0
        while not self._halt.is_set():
            msg = self.bus.recv(0.005)
            if msg is None:
                continue
            data = bytes(msg.data)
            if msg.arbitration_id != self.txid:
                fid = p.FrameId.decode(msg.arbitration_id, msg.is_extended_id)
                if fid is not None and self.key is not None and fid.destination == self.node:
                    self._keyed(fid, data)
                    continue
                if fid:
                    self.others.append((msg.arbitration_id, data))
                continue
            kind = data[0] >> 4
            if self.key is not None and kind in (0, 1):
                # A keyed node takes a first or single frame only after an open of its length.
                length = data[0] & 0xF if kind == 0 else (data[0] & 0xF) << 8 | data[1]
                if self.opened is None or length != self._opened_length:
                    continue
                self._transfer_nonce, self.opened = self.opened, None
            self.frames.append(data)
            if len(data) != 8:
                self.errors.append(f"frame of {len(data)} bytes")
            kind = data[0] >> 4
            if kind == 0:
                length = data[0] & 0xF
                self._complete(data[1 : 1 + length])
            elif kind == 1:
                if self.silent:
                    continue
                expected = (data[0] & 0xF) << 8 | data[1]
                if self.overflow:
                    self._send(self.rxid, bytes([0x32, 0, 0]) + b"\xcc" * 5)
                    self._ack(SchemaAck(SchemaOutcome.TooLong, None, p.NO_ID, 0))
                    continue
                buf = bytearray(data[2:])
                sn, in_block = 1, 0
                self._flow_control()
            elif kind == 2:
                if data[0] & 0xF != sn & 0xF:
                    self.errors.append(f"sequence {data[0] & 0xF}, expected {sn & 0xF}")
                sn += 1
                in_block += 1
                buf += data[1:]
                if len(buf) >= expected:
                    if any(b != 0xCC for b in buf[expected:]):
                        self.errors.append(f"padding {bytes(buf[expected:]).hex()}")
                    self._complete(bytes(buf[:expected]))
                elif in_block == self.block_size:
                    in_block = 0
                    self._flow_control()

    def _flow_control(self) -> None:
        self._send(self.rxid, bytes([0x30, self.block_size, 0]) + b"\xcc" * 5)

    def _keyed(self, fid, data: bytes) -> None:
        if fid.service == p.CHALLENGE_REQUEST and len(data) == 8 and self.refusing:
            # Its checks for the second used up by someone else's bad tags: refused unchecked,
            # and said in one fault for them all (a real node folds a 100 ms window's).
            count, why = self.refusing
            detail = bytes([why, p.CHALLENGE_REQUEST, fid.source, 0, 0])
            self._send(p.frame_id(p.FAULT, self.node, p.BROADCAST),
                       p.Fault(p.FaultCode.Unauthenticated, count, detail).encode())
        elif fid.service == p.CHALLENGE_REQUEST and len(data) == 8:
            # A new node nonce per request; tags are over the exchange of both nonces.
            self.node_nonce += 1
            self.nonce, binding = auth.exchange(self.key, self.node, int.from_bytes(data, "little"),
                                                self.node_nonce)
            if self.unbound_challenges:
                # A made-up challenge first: the client must skip it.
                self.unbound_challenges -= 1
                self._send(p.frame_id(p.CHALLENGE, self.node, fid.source),
                           (self.node_nonce + 1000).to_bytes(6, "little") + b"\x00\x00")
            if self.genuine_challenges:
                self._send(p.frame_id(p.CHALLENGE, self.node, fid.source),
                           self.node_nonce.to_bytes(6, "little") + binding)
        elif fid.service == p.TRANSFER_OPEN and len(data) == 8:
            length, flags = data[0] | data[1] << 8, data[2]
            if data[3:] == auth.open_tag(self.key, self.node, self.nonce, length, flags):
                self.opened, self._opened_length = self.nonce, length

    def _complete(self, message: bytes) -> None:
        if self.key is not None:
            body, mac = message[:-16], message[-16:]
            nonce = self._transfer_nonce
            if mac != auth.image_mac(self.key, self.node, nonce, auth.OPEN_SCHEMA, body):
                self.errors.append("a MAC that does not verify")
                return
            message = body
        self.messages.append(message)
        if self.no_ack:
            return
        channel = message[0] if message else 0xFF
        if channel == SchemaChannel.Limits:
            # The limits channel: decoded, within the table's, or refused whole; no id.
            try:
                limits = s.Limits.decode(message[1:])
                outcome = limits.check_within(self.table_limits) or SchemaOutcome.Accepted
            except s.DecodeError as e:
                limits, outcome = None, e.outcome
            if outcome == SchemaOutcome.Accepted:
                self.limits = limits
            self._ack(SchemaAck(outcome, SchemaChannel.Limits, p.NO_ID, 0, self.stop_number))
            return
        # Bits 0-1 the channel, bits 2-7 the stop number a high-priority schema acknowledges.
        kind, named = channel & 0b11, channel >> 2
        readable = kind == 1 or (kind == 0 and named == 0)
        try:
            schema = s.Schema.decode(message[1:])
        except s.DecodeError:
            schema = None
        if kind == 1 and named != self.stop_number:
            outcome, queued = SchemaOutcome.StopNotAcknowledged, 0
        else:
            outcome, queued = self.answer(kind if readable else channel, schema)
        self._ack(
            SchemaAck(
                outcome,
                SchemaChannel(kind) if readable else None,
                p.NO_ID if schema is None else schema.id,
                queued,
                self.stop_number,
            )
        )

    def _ack(self, ack: SchemaAck) -> None:
        if self.key is not None:
            tag = auth.receipt_tag(self.key, self.node, self._transfer_nonce, ack.encode(), 0,
                                   False)
            if self.forge_receipt:
                tag = bytes(8)
            self._send(p.frame_id(p.RECEIPT, self.node, p.TOOL), tag)
        self._send(p.frame_id(p.SCHEMA_ACK, self.node, p.TOOL), ack.encode())

    def _send(self, arbitration_id: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=True))

    def transition(self, ended, installed, trigger, detail=0, source=SchemaOrigin.Queue, queued=0):
        t = SchemaTransition(ended, installed, trigger, detail, source, queued)
        self._send(p.frame_id(p.SCHEMA_TRANSITION, self.node, p.BROADCAST), t.encode())

    def state(self, **fields) -> SchemaState:
        st = SchemaState(
            **{
                "current": s.WAIT_QUEUE,
                "source": SchemaOrigin.Queue,
                "fault": None,
                "queued": 0,
                "armed": True,
                "gripper_closed": False,
                "elapsed_ms": 0,
                **fields,
            }
        )
        self._send(p.frame_id(p.SCHEMA_STATE, self.node, p.BROADCAST), st.encode())
        return st

    def stop(self) -> None:
        self._halt.set()
        self.join(1)
        self.bus.shutdown()


@pytest.fixture
def rig():
    channel = f"pab-client-{next(_channels)}"
    node = FakeNode(channel)
    node.start()
    # Every test runs with the filters a client's bus is opened with: they pass what it reads.
    bus = can.Bus(interface="virtual", channel=channel, can_filters=client_filters(NODE))
    client = Client(bus, NODE)
    yield client, node
    client.close()
    bus.shutdown()
    node.stop()
    assert node.errors == []


def wait_until(condition, timeout=1.0):
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.005)


def test_install_sends_the_channel_byte_and_the_schema_and_returns_the_ack(rig):
    client, node = rig
    sc = s.move_to(1, (1000, 2000, 3000), 20_000)
    ack = client.install(sc)
    assert ack == SchemaAck(SchemaOutcome.Accepted, SchemaChannel.Queue, 1, 1)
    assert node.messages == [b"\x00" + sc.encode()]
    # A first frame and consecutive frames, every one 8 bytes (padding 0xCC checked by the node).
    assert node.frames[0][0] >> 4 == 1 and all(len(f) == 8 for f in node.frames)


def test_the_high_priority_channel_names_the_stop_the_application_acknowledged(rig):
    client, node = rig
    # Not before a stop is acknowledged: nothing sent.
    with pytest.raises(ClientError, match="acknowledge_stop"):
        client.install(s.idle(1, 100), high_priority=True)
    assert node.messages == []
    node.state()
    assert client.acknowledge_stop() == 0
    ack = client.install(s.idle(2, 100), high_priority=True)
    assert ack.channel == SchemaChannel.HighPriority
    assert node.messages[0][0] == 1
    # The node stops (its third stop): a schema naming stop 0 is refused, and the answer tells
    # the latest; the application acknowledges it and the next one is taken.
    node.stop_number = 3
    with pytest.raises(Refused) as refused:
        client.install(s.idle(3, 100), high_priority=True)
    assert refused.value.outcome == SchemaOutcome.StopNotAcknowledged
    assert refused.value.ack.stop == 3 and client.stop_number == 3
    assert client.acknowledge_stop() == 3
    assert client.install(s.idle(4, 100), high_priority=True).accepted
    assert node.messages[-1][0] == 1 | 3 << 2
    with pytest.raises(ValueError):
        client.acknowledge_stop(64)


def test_a_short_message_is_a_single_frame(rig):
    client, node = rig
    sc = s.relieve(3)
    assert len(sc.encode()) + 1 <= 7
    client.install(sc)
    assert len(node.frames) == 1 and node.frames[0][0] == len(sc.encode()) + 1
    assert node.frames[0][1 + len(sc.encode()) + 1 :] == b"\xcc" * (7 - len(sc.encode()) - 1)


def test_a_long_schema_in_many_blocks():
    channel = f"pab-client-{next(_channels)}"
    node = FakeNode(channel, block_size=2)
    node.start()
    bus = can.Bus(interface="virtual", channel=channel)
    try:
        with Client(bus, NODE) as client:
            reactions = [
                s.Reaction(s.Event.Above(s.Measure.Sensor(i % 8), -(2**31)), s.Source.Innate(i))
                for i in range(16)
            ]
            sc = s.Schema(0x1234, s.Action.MoveTo((1, -2, 3, -4, 5, -6), 7), reactions, 99)
            client.install(sc)
            assert node.messages == [b"\x00" + sc.encode()]
            assert len(node.frames) > 8
    finally:
        bus.shutdown()
        node.stop()
    assert node.errors == []


def test_a_refusal_raises_with_the_nodes_outcome(rig):
    client, node = rig
    node.answer = lambda channel, schema: (SchemaOutcome.Degenerate, 0)
    with pytest.raises(Refused) as e:
        client.install(s.move_to(4, (0, 0, 0), speed=0))
    assert e.value.outcome == SchemaOutcome.Degenerate
    assert e.value.ack.id == 4
    assert "Degenerate" in str(e.value)


def test_an_overflow_is_refused_too_long(rig):
    client, node = rig
    node.overflow = True
    with pytest.raises(Refused) as e:
        client.install(s.move_to(5, (1, 2, 3)))
    assert e.value.outcome == SchemaOutcome.TooLong and e.value.ack.id == p.NO_ID


def test_no_flow_control_is_a_timeout(rig):
    client, node = rig
    node.silent = True
    started = time.monotonic()
    with pytest.raises(Timeout):
        client.install(s.move_to(6, (1, 2, 3)), timeout=0.3)
    assert time.monotonic() - started < 1.5
    # The client recovers: the next transfer goes through.
    node.silent = False
    assert client.install(s.move_to(7, (1, 2, 3))).id == 7


def test_no_ack_is_a_timeout(rig):
    client, node = rig
    node.no_ack = True
    with pytest.raises(Timeout, match="no SchemaAck"):
        client.install(s.grasp(8), timeout=0.3)
    assert len(node.messages) == 1


def test_a_full_queue_is_refused_by_install_and_waited_for_by_install_when_room(rig):
    client, node = rig
    answers = iter([(SchemaOutcome.QueueFull, 8)] * 3 + [(SchemaOutcome.Accepted, 8)])
    node.answer = lambda channel, schema: next(answers)
    with pytest.raises(Refused) as e:
        client.install(s.idle(9, 10))
    assert e.value.outcome == SchemaOutcome.QueueFull

    # The node's queue moves on 0.2 s later: a transition with 7 queued.
    room = threading.Timer(0.2, lambda: node.transition(9, 10, SchemaTrigger.Reaction, queued=7))
    room.start()
    started = time.monotonic()
    try:
        ack = client.install_when_room(s.idle(11, 10), timeout=3, retry_s=1)
    finally:
        room.cancel()
    assert ack.outcome == SchemaOutcome.Accepted and ack.id == 11
    # Refused once more at once, then retried when the transition showed room (not after
    # retry_s), refused again (the queue filled meanwhile, say) and retried after retry_s.
    assert len(node.messages) == 4
    assert 1.15 < time.monotonic() - started < 2.5


def test_install_when_room_gives_up_after_its_timeout(rig):
    client, node = rig
    node.answer = lambda channel, schema: (SchemaOutcome.QueueFull, 8)
    with pytest.raises(Timeout) as e:
        client.install_when_room(s.idle(12, 10), timeout=0.3, retry_s=0.05)
    assert isinstance(e.value.__cause__, Refused)
    assert len(node.messages) >= 2
    # Other refusals are not retried.
    node.answer = lambda channel, schema: (SchemaOutcome.OutOfRange, 0)
    with pytest.raises(Refused):
        client.install_when_room(s.idle(13, 10), timeout=1)


def test_abort_and_emergency_stop_frames(rig):
    client, node = rig
    client.estop()
    client.estop(broadcast=True)
    client.abort()
    client.abort(broadcast=True)
    wait_until(lambda: len(node.others) == 4)
    assert node.others == [
        (0x02000500, b""),
        (0x0200FF00, b""),
        (0x06190500, b""),
        (0x0619FF00, b""),
    ]


def test_convenience_calls_number_their_schemas(rig):
    client, node = rig
    assert client.move_to((1, 2, 3), speed=1000).id == 1
    assert client.move_to_touch((0, 0, -1)).id == 2
    assert client.grasp().id == 3
    assert client.blind_search(depth=500).id == 4
    assert client.release(settle_ms=100).id == 5
    assert client.idle(250).id == 6
    assert client.open_gripper().id == 7
    client.acknowledge_stop(0)
    assert client.close_gripper(high_priority=True).channel == SchemaChannel.HighPriority
    assert client.relieve().id == 9
    assert client.set_impedance(3000, 50).id == 10
    expected = [
        s.move_to(1, (1, 2, 3), 1000),
        s.move_to_touch(2, (0, 0, -1)),
        s.grasp(3),
        s.blind_search(4, depth=500),
        s.release(5, 100),
        s.idle(6, 250),
        s.open_gripper(7),
        s.close_gripper(8),
        s.relieve(9),
        s.set_impedance(10, 3000, 50),
    ]
    assert [s.Schema.decode(m[1:]) for m in node.messages] == expected


def test_ids_wrap_below_the_servers_own():
    bus = can.Bus(interface="virtual", channel=f"pab-client-{next(_channels)}")
    try:
        with Client(bus, NODE, first_id=0xFEFE) as client:
            assert [client.next_id() for _ in range(4)] == [0xFEFE, 0xFEFF, 1, 2]
    finally:
        bus.shutdown()
    with pytest.raises(ValueError):
        Client(bus, 0)


def test_wait_finished_says_which_reaction_ended_the_schema(rig):
    client, node = rig
    touch = client.move_to_touch((0, 0, -1), contact=4000)
    search = client.blind_search()
    node.transition(s.WAIT_QUEUE, touch.id, SchemaTrigger.Reaction, queued=1)
    assert client.wait_started(touch.id, timeout=1).ended == s.WAIT_QUEUE
    node.transition(touch.id, search.id, SchemaTrigger.Reaction, detail=0)
    ended = client.wait_finished(touch.id, timeout=1)
    assert ended.trigger == SchemaTrigger.Reaction
    assert ended.event == s.Event.Above(s.Measure.Contact(), 4000)
    assert ended.reaction.next == s.Source.Queue()
    assert ended.next == search.id and ended.safety is None
    # The search ends on a safety event.
    with pytest.raises(Timeout):
        client.wait_finished(search.id, timeout=0.05)
    node.transition(
        search.id, s.SAFETY + SchemaSafety.Force, SchemaTrigger.Safety, SchemaSafety.Force,
        SchemaOrigin.Innate,
    )
    ended = client.wait_finished(search.id, timeout=1)
    assert ended.safety == SchemaSafety.Force and ended.event is None
    assert ended.next == 0xFF13
    assert [t.installed for t in client.transitions] == [touch.id, search.id, 0xFF13]


def test_a_move_to_touch_that_met_nothing(rig):
    client, node = rig
    touch = client.move_to_touch((0, 0, -1))
    node.transition(touch.id, s.WAIT_HIGH_PRIORITY, SchemaTrigger.Reaction, detail=1,
                    source=SchemaOrigin.HighPriority)
    ended = client.wait_finished(touch.id, timeout=1)
    assert ended.event == s.Event.Done() and ended.reaction.next == s.Source.HighPriority()
    assert ended.reaction_index == 1


def test_a_reinstalled_id_forgets_its_old_ending(rig):
    client, node = rig
    node.transition(1, s.WAIT_QUEUE, SchemaTrigger.Abort)
    wait_until(lambda: len(client.transitions) == 1)
    assert client.wait_finished(1, timeout=0).trigger == SchemaTrigger.Abort
    client.install(s.idle(1, 10))
    with pytest.raises(Timeout):
        client.wait_finished(1, timeout=0.05)


def test_status_is_the_latest_state(rig):
    client, node = rig
    assert client.status() is None
    with pytest.raises(Timeout):
        client.status(timeout=0.05)
    sent = node.state(current=3, queued=2, gripper_closed=True, elapsed_ms=1234)
    wait_until(lambda: client.status() is not None)
    assert client.status() == sent
    threading.Timer(0.05, lambda: node.state(current=4, fault=SchemaSafety.EmergencyStop)).start()
    fresh = client.status(timeout=1)
    assert fresh.current == 4 and fresh.fault == SchemaSafety.EmergencyStop


def test_foreign_and_malformed_reports_are_ignored(rig):
    client, node = rig
    # Another node's state, a state at the wrong priority, an ack to another client.
    other = SchemaState(9, SchemaOrigin.Queue, None, 0, False, False, 0).encode()
    node._send(p.frame_id(p.SCHEMA_STATE, 6, p.BROADCAST), other)
    node._send(p.frame_id(p.SCHEMA_STATE, NODE, p.BROADCAST) & ~(7 << 26), other)
    node._send(p.frame_id(p.SCHEMA_STATE, NODE, p.BROADCAST), other[:7])
    node._send(
        p.frame_id(p.SCHEMA_ACK, NODE, 3),
        SchemaAck(SchemaOutcome.Accepted, SchemaChannel.Queue, 1, 0).encode(),
    )
    wait_until(lambda: client.malformed == 2)
    assert client.status() is None
    # The stray ack is not taken for the next install's.
    node.no_ack = True
    with pytest.raises(Timeout):
        client.install(s.idle(1, 1), timeout=0.2)


def test_the_client_filters_keep_the_rest_of_the_bus_away():
    channel = f"pab-client-{next(_channels)}"
    sender = can.Bus(interface="virtual", channel=channel)
    bus = can.Bus(interface="virtual", channel=channel, can_filters=client_filters(NODE))
    ack = SchemaAck(SchemaOutcome.Accepted, SchemaChannel.Queue, 1, 0).encode()
    passed = [
        (p.transfer_ids(NODE)[1], bytes([0x30, 8, 0]) + b"\xcc" * 5),  # flow control
        (p.frame_id(p.SCHEMA_ACK, NODE, p.TOOL), ack),
        (p.frame_id(p.SCHEMA_TRANSITION, NODE, p.BROADCAST), bytes(8)),
        (p.frame_id(p.SCHEMA_STATE, NODE, p.BROADCAST), bytes(8)),
    ]
    kept_away = [
        (0x310, False, bytes(8)),  # a plant's pose
        (0x310 | NODE << 8, False, bytes(8)),  # a standard id whose low byte is the node's
        (p.frame_id(p.SCHEMA_STATE, NODE + 1, p.BROADCAST), True, bytes(8)),  # another node
        (p.transfer_ids(NODE)[0], True, bytes(8)),  # the client's own transfer to the node
        (0x1605FF00 | NODE, True, bytes(8)),  # the node's heartbeat
        (NODE, True, bytes(8)),  # outside our identifier space
    ]
    try:
        for arbitration_id, extended, data in kept_away:
            sender.send(can.Message(arbitration_id=arbitration_id, is_extended_id=extended,
                                    data=data))
        for arbitration_id, data in passed:
            sender.send(can.Message(arbitration_id=arbitration_id, is_extended_id=True, data=data))
        received = []
        while (msg := bus.recv(timeout=0.2)) is not None:
            received.append((msg.arbitration_id, bytes(msg.data)))
        assert received == passed
    finally:
        bus.shutdown()
        sender.shutdown()
    with pytest.raises(ValueError):
        client_filters(0)


KEY = bytes(range(16))


@pytest.fixture
def keyed_rig():
    channel = f"pab-client-{next(_channels)}"
    node = FakeNode(channel)
    node.key = KEY
    node.start()
    bus = can.Bus(interface="virtual", channel=channel, can_filters=client_filters(NODE))
    yield bus, node
    bus.shutdown()
    node.stop()


def test_with_the_key_every_schema_is_opened_macd_and_confirmed(keyed_rig):
    bus, node = keyed_rig
    with Client(bus, NODE, key=KEY) as client:
        sc = s.move_to(1, (1000, 2000, 3000), 20_000)
        assert client.install(sc).accepted
        assert node.messages == [b"\x00" + sc.encode()]
        assert client.install(s.idle(2, 10)).accepted
    assert node.errors == []


def test_with_the_key_a_challenge_that_does_not_answer_the_request_is_skipped(keyed_rig):
    # A participant answers each request first with a challenge it made up: the client takes
    # only the node's, bound to its own tool nonce, and the schema goes through.
    bus, node = keyed_rig
    node.unbound_challenges = 2
    with Client(bus, NODE, key=KEY) as client:
        assert client.install(s.idle(3, 10)).accepted
        assert client.install(s.idle(4, 10)).accepted
    assert node.unbound_challenges == 0
    assert node.errors == []


def test_with_the_key_only_made_up_challenges_time_out_and_say_so(keyed_rig):
    bus, node = keyed_rig
    node.unbound_challenges = 1
    node.genuine_challenges = False
    with Client(bus, NODE, key=KEY) as client:
        with pytest.raises(Timeout, match="1 that did not"):
            client.install(s.idle(5, 10), timeout=0.3)


def test_with_the_key_a_node_refusing_tags_under_a_flood_says_so(keyed_rig):
    # Someone floods the node with bad tags: it refuses this client's request unchecked, and its
    # fault says so. The client says the node is flooded, not that it is missing from the bus.
    bus, node = keyed_rig
    node.refusing = (37, p.AuthFailure.RateLimited)
    with Client(bus, NODE, key=KEY) as client:
        with pytest.raises(Denied, match="refused 37 tags, more than it checks in a second: "
                                         "someone is flooding") as e:
            client.install(s.idle(6, 10), timeout=0.3)
    assert (e.value.refused, e.value.flooded) == (37, True)
    assert not isinstance(e.value, Timeout)


def test_with_the_key_tags_refused_as_wrong_are_named_so(keyed_rig):
    bus, node = keyed_rig
    node.refusing = (2, p.AuthFailure.BadTag)
    with Client(bus, NODE, key=KEY) as client:
        with pytest.raises(Denied, match="refused 2 tags as wrong") as e:
            client.install(s.idle(7, 10), timeout=0.3)
    assert (e.value.refused, e.value.flooded) == (2, False)
    # The flood over, the next install goes through (refusals count per transfer).
    node.refusing = None
    with Client(bus, NODE, key=KEY) as client:
        assert client.install(s.idle(8, 10)).accepted
    assert node.errors == []


def test_limits_go_on_channel_2_and_a_looser_one_is_refused(rig):
    client, node = rig
    node.table_limits = s.Limits(speed_limit=250_000, joints=[s.Joint(1, -900, 1200, 450)])
    tight = s.Limits(
        force_limit=20_000, speed_limit=100_000, joints=[s.Joint(1, -450, 600, 100)]
    )
    ack = client.set_limits(tight)
    assert ack == SchemaAck(SchemaOutcome.Accepted, SchemaChannel.Limits, p.NO_ID, 0)
    assert node.messages == [b"\x02" + tight.encode()]
    assert node.limits == tight
    # Looser than the table's (no speed limit where it has one): refused whole, nothing set.
    with pytest.raises(Refused) as refused:
        client.set_limits(s.Limits(joints=[s.Joint(1, -450, 600, 100)]))
    assert refused.value.outcome == SchemaOutcome.Looser
    assert refused.value.ack.channel == SchemaChannel.Limits
    assert "refused limits: Looser" in str(refused.value)
    assert node.limits == tight
    # Back up to the table's.
    assert client.set_limits(node.table_limits).accepted
    assert node.limits == node.table_limits
    with pytest.raises(TypeError):
        client.set_limits(s.move_to(1, (0, 0, 0)))


def test_limits_without_an_answer_are_a_timeout(rig):
    client, node = rig
    node.no_ack = True
    with pytest.raises(Timeout, match="limits: no SchemaAck"):
        client.set_limits(s.Limits(), timeout=0.3)
    assert node.messages == [b"\x02" + s.Limits().encode()]


def test_with_the_key_limits_are_opened_macd_and_confirmed_as_schemas(keyed_rig):
    bus, node = keyed_rig
    tight = s.Limits(force_limit=10_000)
    with Client(bus, NODE, key=KEY) as client:
        assert client.set_limits(tight).channel == SchemaChannel.Limits
        assert node.messages == [b"\x02" + tight.encode()]
        assert node.limits == tight
        node.forge_receipt = True
        with pytest.raises(ClientError, match="Receipt for limits does not verify"):
            client.set_limits(s.Limits())
    with Client(bus, NODE, key=bytes(16)) as client:
        with pytest.raises(Timeout):
            client.set_limits(s.Limits(), timeout=0.3)
    assert node.errors == []
    assert len(node.messages) == 2


def test_a_receipt_that_does_not_verify_is_no_answer(keyed_rig):
    bus, node = keyed_rig
    node.forge_receipt = True
    with Client(bus, NODE, key=KEY) as client:
        with pytest.raises(ClientError, match="does not verify"):
            client.install(s.idle(1, 10))


def test_another_key_gets_no_transfer_through(keyed_rig):
    bus, node = keyed_rig
    with Client(bus, NODE, key=bytes(16)) as client:
        with pytest.raises(Timeout):
            client.install(s.idle(1, 10), timeout=0.3)
    assert node.messages == []


def test_a_key_is_sixteen_bytes_and_speaks_as_the_tool():
    bus = can.Bus(interface="virtual", channel="pab-client-keys")
    try:
        with pytest.raises(ValueError):
            Client(bus, NODE, key=bytes(15))
        with pytest.raises(ValueError):
            Client(bus, NODE, source=3, key=KEY)
    finally:
        bus.shutdown()


def test_timeouts_are_seconds_checked_before_anything_is_sent():
    # A NaN timeout never returns from threading.Condition.wait: refused at once, like an
    # infinite one, a negative one, a string and a bool; nothing reaches the bus and no id is
    # used up.
    bus = can.Bus(interface="virtual", channel="pab-client-timeouts")
    listener = can.Bus(interface="virtual", channel="pab-client-timeouts")
    try:
        with Client(bus, NODE) as client:
            first = client.next_id()
            calls = {
                "move_to": lambda t: client.move_to((0, 0, 100), timeout=t),
                "install": lambda t: client.install(s.idle(first, 10), timeout=t),
                "install_when_room": lambda t: client.install_when_room(s.idle(first, 10), retry_s=t),
                "acknowledge_stop": lambda t: client.acknowledge_stop(timeout=t),
                "status": lambda t: client.status(timeout=t),
                "wait_started": lambda t: client.wait_started(first, timeout=t),
                "wait_finished": lambda t: client.wait_finished(first, timeout=t),
            }
            for name, call in calls.items():
                for bad in (math.nan, math.inf, -1.0, MAX_SECONDS * 2, "1", True):
                    started = time.monotonic()
                    with pytest.raises(InvalidArgument, match="seconds"):
                        call(bad)
                    assert time.monotonic() - started < 0.5, (name, bad)
            # Still a ValueError and a ClientError for code that catches those.
            with pytest.raises(ValueError):
                client.status(timeout=math.nan)
            with pytest.raises(ClientError):
                client.status(timeout=math.nan)
            assert listener.recv(timeout=0.1) is None
            assert client.next_id() == first + 1
    finally:
        listener.shutdown()
        bus.shutdown()
