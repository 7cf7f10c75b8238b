"""pab_client.protocol: the identifiers of docs/can-protocol.md's worked examples, the reports'
round trips, and every refusal the nodes' decoder makes."""

import itertools
import json
import pathlib

import pytest

from pab_client import protocol as p
from pab_client.protocol import (
    MalformedFrame,
    SchemaAck,
    SchemaChannel,
    SchemaOrigin,
    SchemaOutcome,
    SchemaSafety,
    SchemaState,
    SchemaTransition,
    SchemaTrigger,
)


def test_identifiers_are_the_documents_examples():
    # docs/can-protocol.md, "Identifiers": the schema server's rows.
    assert p.emergency_stop_id() == 0x0200FF00
    assert p.emergency_stop_id(10) == 0x02000A00
    assert p.emergency_stop_id(5) == 0x02000500
    assert p.abort_id(10) == 0x06190A00
    assert p.transfer_ids(10) == (0x0A1A0A00, 0x0A1A000A)
    assert p.frame_id(p.SCHEMA_ACK, 10, 0) == 0x0A1B000A
    assert p.frame_id(p.SCHEMA_TRANSITION, 10, p.BROADCAST) == 0x0A1CFF0A
    assert p.frame_id(p.SCHEMA_STATE, 10, p.BROADCAST) == 0x161DFF0A
    assert p.FrameId.decode(0x0A1CFF0A) == p.FrameId(2, p.SCHEMA_TRANSITION, 0xFF, 10)
    assert p.FrameId.decode(0x0A1CFF0A, is_extended=False) is None
    assert p.FrameId.decode(0x0B1CFF0A) is None  # another marker
    with pytest.raises(ValueError):
        p.frame_id(p.SCHEMA_ABORT, 0, 256)


CODES = json.loads((pathlib.Path(__file__).parent / "golden_codes.json").read_text())


@pytest.mark.parametrize(
    "enum_type",
    [SchemaOutcome, SchemaSafety, SchemaChannel, SchemaTrigger, SchemaOrigin, p.FaultCode,
     p.AuthFailure],
)
def test_codes_names_and_descriptions_are_the_rust_wire_enums(enum_type):
    # golden_codes.json: pab_core::protocol's wire_enum!s, written by lang/tests/client_golden.rs.
    assert [
        {"code": v.value, "name": v.name, "description": v.description} for v in enum_type
    ] == CODES[enum_type.__name__]


def test_codes_are_the_documents():
    assert [o.value for o in SchemaOutcome] == list(range(0x12))
    assert SchemaOutcome.Looser == 0x11
    assert SchemaOutcome.QueueFull == 0x09 and SchemaOutcome.NoServer == 0x0E
    assert SchemaOutcome.StopNotAcknowledged == 0x0F and SchemaOutcome.TimedOut == 0x10
    assert [c.name for c in SchemaSafety] == [
        "EmergencyStop",
        "StaleSensor",
        "Limit",
        "Force",
        "Watchdog",
        "Overrun",
        "ImplausibleSensor",
        "JointLimit",
        "Speed",
    ]
    assert SchemaSafety.JointLimit == 7 and SchemaSafety.Speed == 8
    assert [c.name for c in SchemaChannel] == ["Queue", "HighPriority", "Limits"]
    assert SchemaOutcome.QueueFull.description.startswith("queue full")


def test_faults_decode_at_priority_0_and_refuse_an_unknown_code():
    # An Unauthenticated fault of node 10: 3 refusals, rate-limited, of ChallengeRequests.
    data = bytes([0x30, 0x00, 3, 0x05, 0x13, 0x00, 0, 0])
    fid, fault = p.decode_fault(p.frame_id(p.FAULT, 10, p.BROADCAST), True, data)
    assert (fid.source, fid.destination, fid.priority) == (10, 0xFF, 0)
    assert fault == p.Fault(p.FaultCode.Unauthenticated, 3, bytes([5, 0x13, 0, 0, 0]))
    assert fault.auth_failure == p.AuthFailure.RateLimited and fault.encode() == data
    assert p.Fault(p.FaultCode.GatesLost, 1, bytes(5)).auth_failure is None
    assert p.frame_id(p.FAULT, 3, p.BROADCAST) == 0x0201FF03  # the document's example
    with pytest.raises(p.MalformedFrame, match="unknown code 0x99"):
        p.Fault.decode(bytes([0x99, 0, 1, 0, 0, 0, 0, 0]))
    with pytest.raises(p.MalformedFrame, match="7 bytes"):
        p.Fault.decode(data[:7])
    with pytest.raises(p.MalformedFrame, match="priority 2"):
        p.decode_fault(p.frame_id(p.FAULT, 10, p.BROADCAST) | 2 << 26, True, data)
    assert p.decode_fault(p.frame_id(p.SCHEMA_ACK, 10, 0), True, data) is None


def test_acks_round_trip():
    for outcome, channel, sid, queued, stop in itertools.product(
        SchemaOutcome, [None, *SchemaChannel], [0, 1, 0xFEFF, 0xFFFF], [0, 8, 255], [0, 63]
    ):
        ack = SchemaAck(outcome, channel, sid, queued, stop)
        data = ack.encode()
        assert len(data) == 8
        assert SchemaAck.decode(data) == ack
    assert SchemaAck.decode(bytes.fromhex("00013412020900 00".replace(" ", ""))) == SchemaAck(
        SchemaOutcome.Accepted, SchemaChannel.HighPriority, 0x1234, 2, 9
    )


def test_acks_refused():
    good = SchemaAck(SchemaOutcome.Accepted, SchemaChannel.Queue, 7, 1).encode()
    for data in (
        good[:7],
        good + b"\x00",
        bytes([0x12]) + good[1:],  # unknown outcome
        good[:1] + b"\x03" + good[2:],  # channel neither 0, 1, 2 nor 0xFF
        good[:5] + b"\x40\x00\x00",  # a stop number of 64
        good[:6] + b"\x01\x00",  # reserved bytes
        good[:7] + b"\x80",
    ):
        with pytest.raises(MalformedFrame):
            SchemaAck.decode(data)


def test_transitions_round_trip_and_refuse_a_detail_against_their_trigger():
    t = SchemaTransition(1, 0xFF00, SchemaTrigger.Reaction, 15, SchemaOrigin.Queue, 0)
    assert SchemaTransition.decode(t.encode()) == t
    for cause in SchemaSafety:
        t = SchemaTransition(5, 0xFF10 + cause, SchemaTrigger.Safety, cause, SchemaOrigin.Innate, 3)
        assert SchemaTransition.decode(t.encode()).safety == cause
    for trigger in (SchemaTrigger.HighPriority, SchemaTrigger.Abort):
        t = SchemaTransition(5, 6, trigger, 0, SchemaOrigin.HighPriority, 0)
        assert SchemaTransition.decode(t.encode()) == t
        with pytest.raises(MalformedFrame):
            SchemaTransition.decode(t.encode()[:5] + b"\x01" + t.encode()[6:])
    good = SchemaTransition(1, 2, SchemaTrigger.Reaction, 0, SchemaOrigin.Queue, 0).encode()
    for data in (
        good[:7],
        good[:4] + b"\x04" + good[5:],  # unknown trigger
        good[:6] + b"\x03" + good[7:],  # unknown source
        SchemaTransition(1, 2, SchemaTrigger.Safety, 0, SchemaOrigin.Innate, 0).encode()[:5]
        + b"\x09\x00\x00",  # unknown safety cause
    ):
        with pytest.raises(MalformedFrame):
            SchemaTransition.decode(data)


def test_states_round_trip_with_their_stop_number_and_refuse_unknown_codes():
    flags = [False, True]
    for fault, armed, closed, stop in itertools.product(
        [None, *SchemaSafety], flags, flags, [0, 1, 63]
    ):
        st = SchemaState(0x1234, SchemaOrigin.Queue, fault, 3, armed, closed, 65535, stop)
        assert SchemaState.decode(st.encode()) == st
    # Byte 5: bit 0 armed, bit 1 gripper closed, bits 2-7 the stop number.
    assert SchemaState.decode(bytes([1, 0, 1, 0xFF, 0, 0b0001_0101, 0, 0])).stop == 5
    good = SchemaState(1, SchemaOrigin.Innate, None, 0, True, False, 10).encode()
    for data in (
        good[:3] + b"\x09" + good[4:],  # unknown safety event
        good[:2] + b"\x03" + good[3:],  # unknown source
        good[:6],
    ):
        with pytest.raises(MalformedFrame):
            SchemaState.decode(data)


def test_reports_are_decoded_only_at_their_services_priority():
    ack = SchemaAck(SchemaOutcome.QueueFull, SchemaChannel.Queue, 3, 8)
    fid, report = p.decode_report(0x0A1B0005, True, ack.encode())
    assert (fid.source, fid.destination, report) == (5, 0, ack)
    state = SchemaState(1, SchemaOrigin.Queue, None, 0, False, False, 0)
    assert p.decode_report(0x161DFF05, True, state.encode())[1] == state
    for priority in range(8):
        if priority == 2:
            continue
        with pytest.raises(MalformedFrame):
            p.decode_report(priority << 26 | 0x021B0005, True, ack.encode())
    # Not a report: other services, standard frames, other markers.
    assert p.decode_report(0x1202FF05, True, bytes(8)) is None
    assert p.decode_report(0x0A1A0005, True, bytes(8)) is None
    assert p.decode_report(0x0A1B0005, False, ack.encode()) is None


def test_transfer_message_is_the_channel_byte_and_the_schema():
    assert p.transfer_message(b"\x01\x02") == b"\x00\x01\x02"
    assert p.transfer_message(b"\x01\x02", high_priority=True) == b"\x01\x01\x02"
    p.transfer_message(bytes(256))
    with pytest.raises(ValueError):
        p.transfer_message(bytes(257))


def test_a_limits_message_is_channel_byte_2_and_the_limits():
    assert p.limits_message(b"\x01\x02") == b"\x02\x01\x02"
    # The limits channel's answer: channel 2, no id.
    ack = SchemaAck.decode(bytes([0x11, 2, 0xFF, 0xFF, 0, 0, 0, 0]))
    assert ack == SchemaAck(SchemaOutcome.Looser, SchemaChannel.Limits, p.NO_ID, 0)
    with pytest.raises(ValueError):
        p.limits_message(bytes(257))
