"""The schema server's frames (docs/can-protocol.md, "Schema server"): identifiers, the reports a
node sends (SchemaAck, SchemaTransition, SchemaState, and its Fault frames) decoded and checked
as the nodes' own decoder (`pab_core::protocol`) checks them, and the frames a client sends (EmergencyStop,
SchemaAbort, the SchemaTransfer message: a schema, or on the limits channel the safety bounds).

Every frame of ours has a 29-bit identifier::

    bit  28..26     25..24    23..16     15..8          7..0
         priority   marker    service    destination    source
         0..7       0b10      8 bits     node or 0xFF   node or 0 (the tool)

and a fixed-length little-endian payload: a frame whose length differs, whose enumerated field
holds an unknown code, whose reserved bits are set, or whose priority is not its service's, is
refused whole (:class:`MalformedFrame`).
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass
from typing import Optional, Union

PROTOCOL_MASK = 0x0300_0000
PROTOCOL_VALUE = 0x0200_0000
#: The workstation's address.
TOOL = 0
#: The broadcast destination.
BROADCAST = 0xFF

EMERGENCY_STOP = 0x00
FAULT = 0x01
CHALLENGE_REQUEST = 0x13
CHALLENGE = 0x14
TRANSFER_OPEN = 0x15
RECEIPT = 0x16
SCHEMA_ABORT = 0x19
SCHEMA_TRANSFER = 0x1A
SCHEMA_ACK = 0x1B
SCHEMA_TRANSITION = 0x1C
SCHEMA_STATE = 0x1D

#: Each service's fixed priority (bits 28..26).
PRIORITY = {
    EMERGENCY_STOP: 0,
    FAULT: 0,
    CHALLENGE_REQUEST: 3,
    CHALLENGE: 2,
    TRANSFER_OPEN: 3,
    RECEIPT: 2,
    SCHEMA_ABORT: 1,
    SCHEMA_TRANSFER: 2,
    SCHEMA_ACK: 2,
    SCHEMA_TRANSITION: 2,
    SCHEMA_STATE: 5,
}

#: A SchemaTransfer message holds a channel byte and at most 256 bytes of schema (or limits).
MAX_MESSAGE = 257
#: SchemaAck's id when the schema could not be decoded.
NO_ID = 0xFFFF
#: SchemaAck's channel byte when the channel could not be read.
NO_CHANNEL = 0xFF
#: SchemaState's byte 3 when the server is not stopped on a safety event.
NO_FAULT = 0xFF


class MalformedFrame(ValueError):
    """A frame of one of our services that breaks its layout: refused whole."""


def frame_id(service: int, source: int, destination: int) -> int:
    """The 29-bit identifier of one of our frames, e.g. ``frame_id(EMERGENCY_STOP, 0, 5)`` is
    0x02000500."""
    for value, what in ((source, "source"), (destination, "destination")):
        if not 0 <= value <= 0xFF:
            raise ValueError(f"{what} {value}: an address is 0..=255")
    return PRIORITY[service] << 26 | 0b10 << 24 | service << 16 | destination << 8 | source


@dataclass(frozen=True)
class FrameId:
    """An identifier of ours, taken apart."""

    priority: int
    service: int
    destination: int
    source: int

    @staticmethod
    def decode(arbitration_id: int, is_extended: bool = True) -> Optional["FrameId"]:
        """The fields, or None for a frame outside our identifier space (a standard frame, or
        another marker)."""
        if not is_extended or arbitration_id & PROTOCOL_MASK != PROTOCOL_VALUE:
            return None
        return FrameId(
            priority=(arbitration_id >> 26) & 0x7,
            service=(arbitration_id >> 16) & 0xFF,
            destination=(arbitration_id >> 8) & 0xFF,
            source=arbitration_id & 0xFF,
        )


class SchemaOutcome(enum.IntEnum):
    """SchemaAck byte 0: accepted, or why the schema was refused (a refused schema changes
    nothing)."""

    Accepted = 0x00
    Malformed = 0x01
    TrailingBytes = 0x02
    ReservedId = 0x03
    BadAxis = 0x04
    BadSensor = 0x05
    OutOfRange = 0x06
    Degenerate = 0x07
    UnknownInnate = 0x08
    QueueFull = 0x09
    Busy = 0x0A
    TooLong = 0x0B
    BadChannel = 0x0C
    Unauthenticated = 0x0D
    NoServer = 0x0E
    StopNotAcknowledged = 0x0F
    TimedOut = 0x10
    Looser = 0x11

    @property
    def description(self) -> str:
        """The one-line description of `pab_core::protocol::SchemaOutcome` (and of
        docs/can-protocol.md's table)."""
        return _OUTCOME_TEXT[self]


_OUTCOME_TEXT = {
    SchemaOutcome.Accepted: "accepted",
    SchemaOutcome.Malformed: "not a schema's (or limits') encoding",
    SchemaOutcome.TrailingBytes: "bytes after the schema",
    SchemaOutcome.ReservedId: "id reserved for the server's own schemas (0xFF00 and up)",
    SchemaOutcome.BadAxis: "axis index of 6 or more",
    SchemaOutcome.BadSensor: "sensor index of 8 or more",
    SchemaOutcome.OutOfRange: "value beyond ±500 m (µm, µrad)",
    SchemaOutcome.Degenerate: "action that would never progress (speed 0, no direction, pitch 0)",
    SchemaOutcome.UnknownInnate: "names an innate schema the board does not have",
    SchemaOutcome.QueueFull: "queue full (8): refused, nothing overwritten",
    SchemaOutcome.Busy: "a high-priority schema is already waiting for the next tick",
    SchemaOutcome.TooLong: "message longer than 273 bytes",
    SchemaOutcome.BadChannel: (
        "channel byte neither the queue, the high-priority channel nor the limits"
    ),
    SchemaOutcome.Unauthenticated: "the message's MAC does not verify (a node with a key)",
    SchemaOutcome.NoServer: "the node's table runs no schema server",
    SchemaOutcome.StopNotAcknowledged: (
        "names another stop than the latest: acknowledge the stop first"
    ),
    SchemaOutcome.TimedOut: "transfer timed out",
    SchemaOutcome.Looser: "limits looser than the table's, or inconsistent",
}

#: Stop numbers count a server's stops (emergency stops, aborts, safety events) modulo this.
STOP_NUMBERS = 64


class SchemaChannel(enum.IntEnum):
    """A SchemaTransfer message's byte 0 (SchemaAck byte 1): the queue, the high-priority
    channel (1 in bits 0-1, the acknowledged stop number in bits 2-7), or the limits (the
    board's safety bounds, :class:`pab_client.schema.Limits`)."""

    Queue = 0
    HighPriority = 1
    Limits = 2

    @property
    def description(self) -> str:
        return _CHANNEL_TEXT[self]


_CHANNEL_TEXT = {
    SchemaChannel.Queue: "queue",
    SchemaChannel.HighPriority: "high-priority channel",
    SchemaChannel.Limits: "limits",
}


class SchemaTrigger(enum.IntEnum):
    """What ended a schema (SchemaTransition byte 4)."""

    HighPriority = 0
    Abort = 1
    Safety = 2
    Reaction = 3

    @property
    def description(self) -> str:
        return _TRIGGER_TEXT[self]


_TRIGGER_TEXT = {
    SchemaTrigger.HighPriority: "high-priority channel",
    SchemaTrigger.Abort: "abort",
    SchemaTrigger.Safety: "safety event",
    SchemaTrigger.Reaction: "reaction",
}


class SchemaOrigin(enum.IntEnum):
    """Where an installed schema came from (SchemaTransition byte 6, SchemaState byte 2)."""

    Innate = 0
    Queue = 1
    HighPriority = 2

    @property
    def description(self) -> str:
        return _ORIGIN_TEXT[self]


_ORIGIN_TEXT = {
    SchemaOrigin.Innate: "innate",
    SchemaOrigin.Queue: "queue",
    SchemaOrigin.HighPriority: "high-priority",
}


class SchemaSafety(enum.IntEnum):
    """A safety event of the server (SchemaTransition detail, SchemaState byte 3). The numbers
    are the order the events came to be; the server tests them (after the emergency stop) in
    this order: stale sensor, implausible pose, workspace limit, joint limit, speed, force,
    watchdog, overrun."""

    EmergencyStop = 0
    StaleSensor = 1
    Limit = 2
    Force = 3
    Watchdog = 4
    Overrun = 5
    ImplausibleSensor = 6
    JointLimit = 7
    Speed = 8

    @property
    def description(self) -> str:
        return _SAFETY_TEXT[self]


_SAFETY_TEXT = {
    SchemaSafety.EmergencyStop: "emergency stop",
    SchemaSafety.StaleSensor: "sensor stale",
    SchemaSafety.Limit: "workspace limit",
    SchemaSafety.Force: "force limit",
    SchemaSafety.Watchdog: "watchdog",
    SchemaSafety.Overrun: "loop overrun",
    SchemaSafety.ImplausibleSensor: "implausible pose",
    SchemaSafety.JointLimit: "joint limit",
    SchemaSafety.Speed: "speed limit",
}


class FaultCode(enum.IntEnum):
    """What a node's Fault frame reports (bytes 0-1). A client reads :attr:`Unauthenticated`
    (with :class:`AuthFailure` in detail byte 0) to tell a flood of bad tags from a silent node;
    the others are listed so that every fault of the bus decodes."""

    BadStoredTable = 0x0001
    TableRefused = 0x0002
    StoreFailed = 0x0003
    BusError = 0x0010
    RxOverrun = 0x0011
    TxOverrun = 0x0012
    BusOff = 0x0013
    BadCommand = 0x0020
    Unauthenticated = 0x0030
    KeyPageInvalid = 0x0031
    ClaimRefused = 0x0040
    GatesLost = 0x0050
    GatesRefused = 0x0051
    DynamicsLate = 0x0052
    FilterRefused = 0x0060
    SchemaSafety = 0x0070
    BitrateFallback = 0x0080
    SettingsUnreadable = 0x0081
    UpdateFailed = 0x0090

    @property
    def description(self) -> str:
        return _FAULT_TEXT[self]


_FAULT_TEXT = {
    FaultCode.BadStoredTable: "stored table refused at boot",
    FaultCode.TableRefused: "pushed table refused",
    FaultCode.StoreFailed: "table could not be stored",
    FaultCode.BusError: "bus error",
    FaultCode.RxOverrun: "receive overrun",
    FaultCode.TxOverrun: "transmit overrun",
    FaultCode.BusOff: "bus-off or error-passive",
    FaultCode.BadCommand: "malformed command",
    FaultCode.Unauthenticated: "configuration refused: not authenticated",
    FaultCode.KeyPageInvalid: "key page invalid: configuration locked",
    FaultCode.ClaimRefused: "BLE claim refused",
    FaultCode.GatesLost: "dynamics gates lost",
    FaultCode.GatesRefused: "dynamics gates refused",
    FaultCode.DynamicsLate: "dynamics steps dropped",
    FaultCode.FilterRefused: "filter command refused",
    FaultCode.SchemaSafety: "schema server stopped by a safety event",
    FaultCode.BitrateFallback: "bit rate fell back",
    FaultCode.SettingsUnreadable: "configuration page unreadable",
    FaultCode.UpdateFailed: "firmware update failed",
}


class AuthFailure(enum.IntEnum):
    """Why a keyed node refused a tagged message: detail byte 0 of an
    :attr:`FaultCode.Unauthenticated` fault."""

    Missing = 0x01
    BadTag = 0x02
    Stale = 0x03
    Broadcast = 0x04
    RateLimited = 0x05
    Unopened = 0x06
    NotTool = 0x07
    Locked = 0x08
    NoKey = 0x09
    Sequence = 0x0A
    BadSeal = 0x0B
    Unsealed = 0x0C
    Unsynced = 0x0D

    @property
    def description(self) -> str:
        return _AUTH_TEXT[self]


_AUTH_TEXT = {
    AuthFailure.Missing: "no tag, and the node has a key",
    AuthFailure.BadTag: "wrong tag",
    AuthFailure.Stale: "no fresh challenge",
    AuthFailure.Broadcast: "broadcast configuration refused",
    AuthFailure.RateLimited: "too many tag checks",
    AuthFailure.Unopened: "transfer not opened",
    AuthFailure.NotTool: "transfer from a source other than the tool",
    AuthFailure.Locked: "configuration locked: key page invalid",
    AuthFailure.NoKey: "tagged message to a node without a key",
    AuthFailure.Sequence: "consecutive frame out of sequence ignored",
    AuthFailure.BadSeal: "seal does not verify",
    AuthFailure.Unsealed: "no seal",
    AuthFailure.Unsynced: "sender not synchronised yet",
}


def _code(enum_type, code: int, what: str):
    try:
        return enum_type(code)
    except ValueError:
        raise MalformedFrame(f"{what}: unknown code {code:#04x}") from None


def _length(data: bytes, n: int, what: str) -> bytes:
    data = bytes(data)
    if len(data) != n:
        raise MalformedFrame(f"{what}: {len(data)} bytes, not {n}")
    return data


@dataclass(frozen=True)
class SchemaAck:
    """A node's answer to one SchemaTransfer message (service 0x1B, node → its sender)."""

    outcome: SchemaOutcome
    #: The message's channel; None when it could not be read (0xFF on the wire).
    channel: Optional[SchemaChannel]
    #: The schema's id; NO_ID (0xFFFF) when it could not be decoded, and for limits.
    id: int
    #: Schemas in the queue after this one.
    queued: int
    #: The server's stop number when it answered (what a StopNotAcknowledged refusal wanted).
    stop: int = 0

    @property
    def accepted(self) -> bool:
        return self.outcome == SchemaOutcome.Accepted

    @staticmethod
    def decode(data: bytes) -> "SchemaAck":
        data = _length(data, 8, "SchemaAck")
        if data[6:8] != b"\x00\x00":
            raise MalformedFrame("SchemaAck: reserved bytes 6-7 not 0")
        if data[5] >= STOP_NUMBERS:
            raise MalformedFrame(f"SchemaAck: stop number {data[5]}, not below {STOP_NUMBERS}")
        channel = (
            None if data[1] == NO_CHANNEL else _code(SchemaChannel, data[1], "SchemaAck channel")
        )
        return SchemaAck(
            outcome=_code(SchemaOutcome, data[0], "SchemaAck outcome"),
            channel=channel,
            id=data[2] | data[3] << 8,
            queued=data[4],
            stop=data[5],
        )

    def encode(self) -> bytes:
        channel = NO_CHANNEL if self.channel is None else int(self.channel)
        return struct.pack(
            "<BBHBB2x", int(self.outcome), channel, self.id, self.queued, self.stop % STOP_NUMBERS
        )


@dataclass(frozen=True)
class SchemaTransition:
    """A schema change of a node's server (service 0x1C, node → all): `ended` gave way to
    `installed`. A client's schema started when it is `installed`, finished when it is
    `ended`."""

    ended: int
    installed: int
    trigger: SchemaTrigger
    #: The safety cause (trigger Safety) or the reaction's index in the ended schema's table
    #: (trigger Reaction); 0 otherwise.
    detail: int
    #: Where the installed schema came from.
    source: SchemaOrigin
    #: Schemas in the queue after the change.
    queued: int

    @property
    def safety(self) -> Optional[SchemaSafety]:
        """The safety event that ended the schema, for a Safety trigger."""
        if self.trigger == SchemaTrigger.Safety:
            return SchemaSafety(self.detail)
        return None

    @staticmethod
    def decode(data: bytes) -> "SchemaTransition":
        data = _length(data, 8, "SchemaTransition")
        ended, installed, trigger, detail, source, queued = struct.unpack("<HHBBBB", data)
        t = SchemaTransition(
            ended=ended,
            installed=installed,
            trigger=_code(SchemaTrigger, trigger, "SchemaTransition trigger"),
            detail=detail,
            source=_code(SchemaOrigin, source, "SchemaTransition source"),
            queued=queued,
        )
        # The detail must fit the trigger (`SchemaTransition::is_valid`).
        if t.trigger in (SchemaTrigger.HighPriority, SchemaTrigger.Abort) and detail != 0:
            raise MalformedFrame(f"SchemaTransition: detail {detail} after {t.trigger.name}")
        if t.trigger == SchemaTrigger.Safety:
            _code(SchemaSafety, detail, "SchemaTransition safety cause")
        return t

    def encode(self) -> bytes:
        return struct.pack(
            "<HHBBBB",
            self.ended,
            self.installed,
            int(self.trigger),
            self.detail,
            int(self.source),
            self.queued,
        )


@dataclass(frozen=True)
class SchemaState:
    """A node's server state (service 0x1D, node → all, every 100 ms)."""

    #: The installed schema's id.
    current: int
    source: SchemaOrigin
    #: The safety event the server is stopped on; None when running.
    fault: Optional[SchemaSafety]
    queued: int
    #: A pose has been received: the attractor means something.
    armed: bool
    gripper_closed: bool
    #: ms since the schema was installed, saturating at 65 535.
    elapsed_ms: int
    #: The stop number: the server's stops so far modulo 64, which a high-priority schema names
    #: to leave the latest one.
    stop: int = 0

    @staticmethod
    def decode(data: bytes) -> "SchemaState":
        data = _length(data, 8, "SchemaState")
        current, source, fault, queued, flags, elapsed = struct.unpack("<HBBBBH", data)
        return SchemaState(
            current=current,
            source=_code(SchemaOrigin, source, "SchemaState source"),
            fault=None if fault == NO_FAULT else _code(SchemaSafety, fault, "SchemaState fault"),
            queued=queued,
            armed=bool(flags & 1),
            gripper_closed=bool(flags & 2),
            elapsed_ms=elapsed,
            stop=flags >> 2,
        )

    def encode(self) -> bytes:
        fault = NO_FAULT if self.fault is None else int(self.fault)
        flags = int(self.armed) | int(self.gripper_closed) << 1 | (self.stop % STOP_NUMBERS) << 2
        return struct.pack(
            "<HBBBBH",
            self.current,
            int(self.source),
            fault,
            self.queued,
            flags,
            self.elapsed_ms,
        )


@dataclass(frozen=True)
class Fault:
    """A node's fault (service 0x01, node → all, priority 0), at most one per code per 100 ms:
    `count` says how many times it happened since the last frame with this code."""

    code: FaultCode
    #: Occurrences since the last frame with this code, 1..255 (saturating).
    count: int
    #: Code-specific detail (docs/can-protocol.md, FaultCode); 0 where unused.
    detail: bytes

    @staticmethod
    def decode(data: bytes) -> "Fault":
        data = _length(data, 8, "Fault")
        return Fault(
            code=_code(FaultCode, data[0] | data[1] << 8, "Fault code"),
            count=data[2],
            detail=data[3:8],
        )

    def encode(self) -> bytes:
        if len(self.detail) != 5:
            raise ValueError(f"a fault's detail is 5 bytes, not {len(self.detail)}")
        return struct.pack("<HB", int(self.code), self.count) + bytes(self.detail)

    @property
    def auth_failure(self) -> Optional[AuthFailure]:
        """Why a tagged message was refused, for an Unauthenticated fault (None for another
        code, or a reason this client does not know)."""
        if self.code != FaultCode.Unauthenticated:
            return None
        try:
            return AuthFailure(self.detail[0])
        except ValueError:
            return None


def decode_fault(
    arbitration_id: int, is_extended: bool, data: bytes
) -> Optional["tuple[FrameId, Fault]"]:
    """A node's Fault frame with its identifier's fields; None for any other frame. Raises
    :class:`MalformedFrame` for a Fault at another priority or with a broken payload."""
    fid = FrameId.decode(arbitration_id, is_extended)
    if fid is None or fid.service != FAULT:
        return None
    if fid.priority != PRIORITY[FAULT]:
        raise MalformedFrame(f"Fault: priority {fid.priority}, not {PRIORITY[FAULT]}")
    return fid, Fault.decode(data)


Report = Union[SchemaAck, SchemaTransition, SchemaState]

_REPORTS = {
    SCHEMA_ACK: SchemaAck,
    SCHEMA_TRANSITION: SchemaTransition,
    SCHEMA_STATE: SchemaState,
}


def decode_report(
    arbitration_id: int, is_extended: bool, data: bytes
) -> Optional["tuple[FrameId, Report]"]:
    """A schema server's report (SchemaAck, SchemaTransition or SchemaState) with its
    identifier's fields; None for any other frame. Raises :class:`MalformedFrame` for one of
    those services at another priority or with a broken payload."""
    fid = FrameId.decode(arbitration_id, is_extended)
    if fid is None or fid.service not in _REPORTS:
        return None
    if fid.priority != PRIORITY[fid.service]:
        raise MalformedFrame(
            f"{_REPORTS[fid.service].__name__}: priority {fid.priority}, "
            f"not {PRIORITY[fid.service]}"
        )
    return fid, _REPORTS[fid.service].decode(data)


def emergency_stop_id(destination: int = BROADCAST, source: int = TOOL) -> int:
    """EmergencyStop's identifier: 0x0200FF00 from the tool to all, 0x0200NN00 to node NN. The
    frame has no payload (a padded one is malformed)."""
    return frame_id(EMERGENCY_STOP, source, destination)


def abort_id(destination: int = BROADCAST, source: int = TOOL) -> int:
    """SchemaAbort's identifier: 0x0619NN00 from the tool to node NN. No payload."""
    return frame_id(SCHEMA_ABORT, source, destination)


def transfer_ids(node: int, source: int = TOOL) -> "tuple[int, int]":
    """The SchemaTransfer identifiers of a client and a node: (client → node data, node → client
    flow control), e.g. (0x0A1A0A00, 0x0A1A000A) for node 10."""
    return frame_id(SCHEMA_TRANSFER, source, node), frame_id(SCHEMA_TRANSFER, node, source)


def client_filters(node: int) -> "list[dict]":
    """python-can ``can_filters`` that pass what a client of `node` reads, and nothing else:
    the node's flow control for the client's transfers, its reports (SchemaAck,
    SchemaTransition, SchemaState), its faults (a keyed node says there that it refused tags),
    and on a node with a key its Challenge and Receipt, whatever their destination.

    On SocketCAN the kernel applies them, so a client's process never sees the rest of the bus:
    a plant publishing pose and wrench at 1 kHz would otherwise reach the client's notifier
    thread too, and under load bury the node's flow control and answers behind thousands of
    frames the client ignores."""
    if not 1 <= node <= 127:
        raise ValueError(f"node {node}: nodes are 1..=127")
    return [
        {
            "can_id": PROTOCOL_VALUE | service << 16 | node,
            "can_mask": PROTOCOL_MASK | 0xFF << 16 | 0xFF,
            "extended": True,
        }
        for service in (SCHEMA_TRANSFER, CHALLENGE, RECEIPT, FAULT, *_REPORTS)
    ]


def transfer_message(schema_bytes: bytes, high_priority: bool = False, stop: int = 0) -> bytes:
    """A SchemaTransfer message: the channel byte and the schema's encoding. The channel byte is
    0 for the queue; for the high-priority channel 1, with the stop number the client
    acknowledges (`stop`, 0..63: the latest its SchemaState showed) in bits 2-7."""
    if not 0 <= stop < STOP_NUMBERS:
        raise ValueError(f"stop number {stop}: 0..{STOP_NUMBERS - 1}")
    channel = 1 | stop << 2 if high_priority else 0
    message = bytes([channel]) + bytes(schema_bytes)
    if len(message) > MAX_MESSAGE:
        raise ValueError(f"a schema message is at most {MAX_MESSAGE} bytes, not {len(message)}")
    return message


def limits_message(limits_bytes: bytes) -> bytes:
    """A SchemaTransfer message on the limits channel: the channel byte 2 and the encoding of
    :class:`pab_client.schema.Limits`."""
    message = bytes([SchemaChannel.Limits]) + bytes(limits_bytes)
    if len(message) > MAX_MESSAGE:
        raise ValueError(f"a limits message is at most {MAX_MESSAGE} bytes, not {len(message)}")
    return message
