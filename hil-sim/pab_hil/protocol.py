"""The node frames the harness reads and the one it writes (the diagnostic stream's switch).

Decoding only: the layouts are those of `docs/can-protocol.md`, whose only implementation is
`pab_core::protocol`. Nothing here arbitrates; the nodes do, and tell us what they decided.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

PROTOCOL_MASK = 0x0300_0000
PROTOCOL_VALUE = 0x0200_0000
TOOL = 0
BROADCAST = 0xFF

FAULT = 0x01
HEARTBEAT = 0x02
TABLE_STATUS = 0x03
TRAFFIC = 0x04
ERRORS = 0x05
DIAGNOSTIC = 0x06
GATES = 0x07  # a competitive-dynamics group's gates, from the node that runs it
# HBBA (docs/can-protocol.md, "HBBA message filters"): desires, the intention node's intention,
# the nodes' filter status and exploitation edges, and the intention node's filter commands.
DESIRE = 0x08
INTENTION = 0x09
FILTER_STATUS = 0x0A
EXPLOITATION = 0x0B
DIAGNOSTIC_CONTROL = 0x10
TABLE_TRANSFER = 0x11
TRANSFER_STATUS = 0x12
# Authenticated configuration (docs/can-protocol.md): the harness names them, it does not speak
# them (its nodes run without keys; scripts/keyed-board-test.sh drives a keyed board).
CHALLENGE_REQUEST = 0x13
CHALLENGE = 0x14
TRANSFER_OPEN = 0x15
RECEIPT = 0x16
FILTER_PROFILE = 0x17
FILTER_SET = 0x18
# The schema server (docs/can-protocol.md, "Schema server"): the harness names them; the client
# that speaks them is `pab_client` (client/python).
EMERGENCY_STOP = 0x00
SCHEMA_ABORT = 0x19
SCHEMA_TRANSFER = 0x1A
SCHEMA_ACK = 0x1B
SCHEMA_TRANSITION = 0x1C
SCHEMA_STATE = 0x1D
# Sealed coordination on keyed networks (docs/can-protocol.md, "Sealed coordination"): the
# harness names them; its nodes run without keys.
SEAL = 0x1E
FRESHNESS_REQUEST = 0x1F
FRESHNESS = 0x20
# Identity and configuration (docs/can-protocol.md, "Identity and configuration"): the harness
# names them; the tests drive them through `pabctl nodes`, `assign` and `config`.
IDENTITY_REQUEST = 0x21
IDENTITY = 0x22
IDENTITY_VERSION = 0x23
IDENTITY_BUILD = 0x24
IDENTITY_CAPACITY = 0x25
IDENTITY_FEATURES = 0x26
IDENTITY_NAME = 0x27
ASSIGN = 0x28
CONFIGURE = 0x29
CONFIG_STATUS = 0x2A
# Firmware update over the bus (docs/firmware-update.md): the tests drive it through `pabctl flash`.
UPDATE_TRANSFER = 0x2B
UPDATE_STATUS = 0x2C
INTENTION_NODE = 126  # the intention node's address unless told otherwise

PRIORITY = {
    FAULT: 0,
    HEARTBEAT: 4,
    TABLE_STATUS: 4,
    TRAFFIC: 5,
    ERRORS: 5,
    DIAGNOSTIC: 7,
    GATES: 3,
    DESIRE: 4,
    INTENTION: 4,
    FILTER_STATUS: 4,
    EXPLOITATION: 5,
    DIAGNOSTIC_CONTROL: 3,
    TABLE_TRANSFER: 6,
    TRANSFER_STATUS: 2,
    CHALLENGE_REQUEST: 3,
    CHALLENGE: 2,
    TRANSFER_OPEN: 3,
    RECEIPT: 2,
    FILTER_PROFILE: 3,
    FILTER_SET: 3,
    EMERGENCY_STOP: 0,
    SCHEMA_ABORT: 1,
    SCHEMA_TRANSFER: 2,
    SCHEMA_ACK: 2,
    SCHEMA_TRANSITION: 2,
    SCHEMA_STATE: 5,
    SEAL: 5,
    FRESHNESS_REQUEST: 4,
    FRESHNESS: 4,
    IDENTITY_REQUEST: 3,
    IDENTITY: 4,
    IDENTITY_VERSION: 4,
    IDENTITY_BUILD: 4,
    IDENTITY_CAPACITY: 4,
    IDENTITY_FEATURES: 4,
    IDENTITY_NAME: 4,
    ASSIGN: 3,
    CONFIGURE: 3,
    CONFIG_STATUS: 2,
    UPDATE_TRANSFER: 6,
    UPDATE_STATUS: 2,
}

NODE_STATES = {0: "no table", 1: "operational", 2: "fault"}

TRANSFER_STATUS_CODES = {
    0x00: "Applied",
    0x01: "AlreadyCurrent",
    0x02: "AppliedNotStored",
    0x10: "Interrupted",
    0x11: "Timeout",
    0x12: "TooLarge",
    0x13: "BadHeader",
    0x14: "WrongNode",
    0x15: "OlderVersion",
    0x16: "CrcMismatch",
    0x17: "InvalidTable",
    0x18: "Busy",
    0x19: "Unauthenticated",
}


def frame_id(service: int, source: int, destination: int) -> int:
    """The 29-bit identifier of one of our frames."""
    return (
        PRIORITY[service] << 26
        | 0b10 << 24
        | service << 16
        | destination << 8
        | source
    )


@dataclass(frozen=True)
class FrameId:
    service: int
    destination: int
    source: int

    @staticmethod
    def decode(arbitration_id: int, is_extended: bool) -> "FrameId | None":
        """Our identifier's fields, or None for any frame outside our identifier space."""
        if not is_extended or arbitration_id & PROTOCOL_MASK != PROTOCOL_VALUE:
            return None
        return FrameId(
            service=(arbitration_id >> 16) & 0xFF,
            destination=(arbitration_id >> 8) & 0xFF,
            source=arbitration_id & 0xFF,
        )


@dataclass(frozen=True)
class Heartbeat:
    state: str
    uptime_s: int
    table_version: int

    @staticmethod
    def decode(data: bytes) -> "Heartbeat":
        _expect(data, 8, "Heartbeat")
        state = NODE_STATES.get(data[0], f"unknown state {data[0]}")
        uptime = data[1] | data[2] << 8 | data[3] << 16
        (version,) = struct.unpack_from("<I", data, 4)
        return Heartbeat(state, uptime, version)


@dataclass(frozen=True)
class TableStatus:
    crc: int
    length: int
    ports: int
    stored: bool
    streaming: bool

    @staticmethod
    def decode(data: bytes) -> "TableStatus":
        _expect(data, 8, "TableStatus")
        crc, length, ports, flags = struct.unpack("<IHBB", data)
        return TableStatus(crc, length, ports, bool(flags & 1), bool(flags & 2))


@dataclass(frozen=True)
class Traffic:
    received: int
    delivered: int

    @staticmethod
    def decode(data: bytes) -> "Traffic":
        _expect(data, 8, "Traffic")
        return Traffic(*struct.unpack("<II", data))


@dataclass(frozen=True)
class Errors:
    discarded: int
    errors: int

    @staticmethod
    def decode(data: bytes) -> "Errors":
        _expect(data, 8, "Errors")
        return Errors(*struct.unpack("<II", data))


@dataclass(frozen=True)
class DiagnosticSample:
    """One connection's state in one round of a node's diagnostic stream."""

    port: int
    connection: int
    active: bool
    resting: bool
    delivering: bool
    end_of_round: bool
    sequence: int
    level: float

    @staticmethod
    def decode(data: bytes) -> "DiagnosticSample":
        _expect(data, 8, "Diagnostic")
        port, connection, flags, sequence, raw = struct.unpack("<BBBBI", data)
        return DiagnosticSample(
            port,
            connection,
            bool(flags & 1),
            bool(flags & 2),
            bool(flags & 4),
            bool(flags & 8),
            sequence,
            raw / 2**31,
        )


@dataclass(frozen=True)
class TransferStatus:
    status: str
    detail: int
    version: int

    @staticmethod
    def decode(data: bytes) -> "TransferStatus":
        _expect(data, 8, "TransferStatus")
        code, detail, version = struct.unpack_from("<BBI", data)
        return TransferStatus(TRANSFER_STATUS_CODES.get(code, f"code {code}"), detail, version)


# FaultCode RxOverrun: received frames were lost before the node read them; detail bytes 0-3 the
# frames lost since boot, as the node counted them (u32 LE, saturating).
RX_OVERRUN = 0x0011


@dataclass(frozen=True)
class Fault:
    code: int
    occurrences: int
    detail: bytes

    @property
    def frames_lost(self) -> int:
        """RxOverrun's detail: the frames the node lost since boot."""
        return int.from_bytes(self.detail[:4], "little")

    @staticmethod
    def decode(data: bytes) -> "Fault":
        _expect(data, 8, "Fault")
        (code,) = struct.unpack_from("<H", data)
        return Fault(code, data[2], bytes(data[3:8]))


def diagnostic_control(rate_hz: int, ports: int = 0xFFFF) -> bytes:
    """The payload that switches a node's diagnostic stream (0 Hz: off)."""
    if not 0 <= rate_hz <= 200:
        raise ValueError(f"diagnostic rate {rate_hz} Hz is outside 0..=200")
    return struct.pack("<HH", rate_hz, ports)


DECODERS = {
    HEARTBEAT: Heartbeat.decode,
    TABLE_STATUS: TableStatus.decode,
    TRAFFIC: Traffic.decode,
    ERRORS: Errors.decode,
    DIAGNOSTIC: DiagnosticSample.decode,
    TRANSFER_STATUS: TransferStatus.decode,
    FAULT: Fault.decode,
}


class MalformedFrame(ValueError):
    pass


def _expect(data: bytes, length: int, what: str) -> None:
    if len(data) != length:
        raise MalformedFrame(f"{what} frame with {len(data)} bytes (expected {length})")


# Broadcast of Local Eligibility (docs/can-protocol.md): the claim frames the nodes of a peer group
# send each other. The harness only reads them, to measure what the nodes did.
CLAIM_PRIORITY = 4


@dataclass(frozen=True)
class Claim:
    group: int
    node: int
    eligibility: int

    @staticmethod
    def decode(arbitration_id: int, is_extended: bool, payload: bytes) -> "Claim | None":
        """The claim a frame carries, or None: not a claim, or one a node would refuse."""
        if not is_extended or arbitration_id >> 23 & 0b111 != 0b101:
            return None
        node = arbitration_id & 0x7F
        ranked = 0xFFFF - (arbitration_id >> 7 & 0xFFFF)
        if (arbitration_id >> 26 != CLAIM_PRIORITY or node == 0 or len(payload) != 4
                or payload[3] != 0):
            return None
        group, eligibility = payload[0], int.from_bytes(payload[1:3], "little")
        return Claim(group, node, eligibility) if eligibility == ranked else None

    def arbitration_id(self) -> int:
        return (CLAIM_PRIORITY << 26 | 0b10 << 24 | 1 << 23 | (0xFFFF - self.eligibility) << 7
                | self.node)
