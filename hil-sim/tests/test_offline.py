"""Checks that need no bus: the harness's constants against the project's documents and network
file, and the world's rules of motion."""

from __future__ import annotations

import re
import time
import tomllib

from pab_hil import behaviours as b, protocol as p, world as w
from pab_hil.nodes import NODE_IDS, REPO, TAKE_AND_RETURN

PROTOCOL_DOC = (REPO / "docs" / "can-protocol.md").read_text()


def doc_tables(header: str) -> list[list[list[str]]]:
    """Every markdown table of the protocol document whose header line is `header`: rows of cells."""
    tables: list[list[list[str]]] = []
    current: list[list[str]] | None = None
    for line in PROTOCOL_DOC.splitlines():
        if line.strip() == header:
            current = []
            tables.append(current)
        elif current is not None and line.startswith("|"):
            cells = [cell.strip() for cell in line.strip("|").split("|")]
            if not set("".join(cells)) <= {"-", " "}:
                current.append(cells)
        else:
            current = None
    return tables


def test_identifiers_match_the_protocol_document():
    services = {"Heartbeat": p.HEARTBEAT, "Fault": p.FAULT, "TableStatus": p.TABLE_STATUS,
                "Traffic": p.TRAFFIC, "Errors": p.ERRORS, "Diagnostic": p.DIAGNOSTIC,
                "Gates": p.GATES, "Desire": p.DESIRE, "Intention": p.INTENTION,
                "FilterStatus": p.FILTER_STATUS, "Exploitation": p.EXPLOITATION,
                "FilterProfile": p.FILTER_PROFILE, "FilterSet": p.FILTER_SET,
                "DiagnosticControl": p.DIAGNOSTIC_CONTROL, "TableTransfer": p.TABLE_TRANSFER,
                "TransferStatus": p.TRANSFER_STATUS, "ChallengeRequest": p.CHALLENGE_REQUEST,
                "Challenge": p.CHALLENGE, "TransferOpen": p.TRANSFER_OPEN, "Receipt": p.RECEIPT,
                "EmergencyStop": p.EMERGENCY_STOP, "SchemaAbort": p.SCHEMA_ABORT,
                "SchemaTransfer": p.SCHEMA_TRANSFER, "SchemaAck": p.SCHEMA_ACK,
                "SchemaTransition": p.SCHEMA_TRANSITION, "SchemaState": p.SCHEMA_STATE,
                "UpdateTransfer": p.UPDATE_TRANSFER, "UpdateStatus": p.UPDATE_STATUS}
    (rows,) = doc_tables("| frame | service | source | destination | identifier |")
    assert len(rows) == 33
    for frame, service, source, destination, identifier in rows:
        ident = p.frame_id(services[service], int(source, 0), int(destination, 0))
        assert ident == int(identifier, 16), frame
        decoded = p.FrameId.decode(ident, True)
        assert (decoded.service, decoded.source, decoded.destination) == (
            services[service], int(source, 0), int(destination, 0))


def test_transfer_status_codes_match_the_protocol_document():
    # The node states, the transfer statuses, then the firmware update's statuses (not the
    # harness's business: pabctl flash reads them).
    node_states, transfer_statuses, _update_statuses = doc_tables(
        "| code | name | description | meaning |")
    assert {int(code): description for code, _, description, _ in node_states} == p.NODE_STATES
    documented = {int(code, 16): name for code, name, *_ in transfer_statuses}
    assert documented == p.TRANSFER_STATUS_CODES


def test_the_rx_overrun_fault_code_and_detail_match_the_protocol_document():
    (faults,) = doc_tables("| code | name | description | detail (bytes 3-7) |")
    rows = {int(code, 16): (name, detail) for code, name, _, detail in faults}
    name, detail = rows[p.RX_OVERRUN]
    assert name == "RxOverrun"
    assert detail.startswith("bytes 0-3: the frames lost since boot") and "u32 LE" in detail
    fault = p.Fault.decode(bytes.fromhex("1100" "02" "39300000" "00"))
    assert (fault.code, fault.occurrences, fault.frames_lost) == (p.RX_OVERRUN, 2, 12345)


def test_payload_examples_of_the_protocol_document_decode():
    heartbeat = p.Heartbeat.decode(bytes.fromhex("0156341207000000"))
    assert heartbeat == p.Heartbeat("operational", 0x123456, 7)
    sample = p.DiagnosticSample.decode(bytes.fromhex("020F0DC800000040"))
    assert (sample.port, sample.connection, sample.sequence, sample.level) == (2, 15, 200, 0.5)
    assert sample.active and sample.delivering and sample.end_of_round and not sample.resting
    status = p.TransferStatus.decode(bytes.fromhex("0000040302010000"))
    assert status == p.TransferStatus("Applied", 0, 0x01020304)
    assert p.diagnostic_control(10) == bytes.fromhex("0A00FFFF")
    assert re.search(r"data `0A 00 FF FF`", PROTOCOL_DOC)


def test_the_claim_examples_of_the_protocol_document_decode():
    # "node 2 offering 1000 (0x03E8) sends `0x12FE0B82`"; node 3: 0x12FE0B83; node 1 at 999: 0x12FE0C01
    assert "node 2 offering 1000 (0x03E8) sends `0x12FE0B82`" in PROTOCOL_DOC
    for node, eligibility, ident in ((2, 1000, 0x12FE0B82), (3, 1000, 0x12FE0B83),
                                     (1, 999, 0x12FE0C01)):
        claim = p.Claim(5, node, eligibility)
        assert claim.arbitration_id() == ident
        payload = bytes([5]) + eligibility.to_bytes(2, "little") + b"\0"
        assert p.Claim.decode(ident, True, payload) == claim
    # Refused whole: payload and identifier disagree, a reserved byte set, short, standard id.
    assert p.Claim.decode(0x12FE0B82, True, bytes([5, 0xE7, 0x03, 0])) is None
    assert p.Claim.decode(0x12FE0B82, True, bytes([5, 0xE8, 0x03, 1])) is None
    assert p.Claim.decode(0x12FE0B82, True, bytes([5, 0xE8, 0x03])) is None
    assert p.Claim.decode(0x12FE0B82 & 0x7FF, False, bytes([5, 0xE8, 0x03, 0])) is None
    # A heartbeat of ours is not a claim (bit 23 clear).
    assert p.Claim.decode(p.frame_id(p.HEARTBEAT, 2, p.BROADCAST), True, bytes(8)) is None


def test_behaviours_publish_the_topics_of_the_network_file():
    network = tomllib.loads(TAKE_AND_RETURN.read_text())
    topic_ids = {spec["can_id"] for spec in network["topics"].values()}
    published = {topic for behaviour in b.BEHAVIOURS.values() for topic in behaviour.topics}
    assert published == topic_ids
    assert {name: spec["id"] for name, spec in network["nodes"].items()} == NODE_IDS
    republish = {port: spec["republish"]["can_id"] for port, spec in network["ports"].items()}
    assert republish == {"arm.target": w.ARM_TARGET_ID, "gaze.target": w.GAZE_TARGET_ID,
                         "hand.command": w.HAND_COMMAND_ID}


def test_the_arm_moves_only_on_fresh_targets_and_the_hand_hands_over_only_near_the_face():
    world = w.World()
    target = (150.0, -200.0, 50.0)  # 300 mm above the rest pose
    world.on_delivery(w.ARM_TARGET_ID, w.encode_position(target, 0, 7), time.time())
    world.step(0.5)
    moved = world.snapshot().hand
    assert abs(w.distance(moved, w.REST_POSE) - w.ARM_SPEED * 0.5) < 1e-6
    time.sleep(w.ARM_COMMAND_TIMEOUT + 0.05)
    world.step(0.5)  # no fresh target: the arm holds still
    assert world.snapshot().hand == moved

    # The object in the closed hand, away from the face: opening drops it.
    world._set_many(holder=w.HAND, closure=1.0)
    world.on_delivery(w.HAND_COMMAND_ID, w.encode_command(w.OPEN, 0, 4), time.time())
    for _ in range(10):
        world.step(0.05)
    assert world.snapshot().holder == w.NOBODY
    # At the face, with the person there: the person takes it.
    world._set_many(holder=w.HAND, closure=1.0, hand=w.FACE_AT, face_present=1.0)
    for _ in range(10):
        world.step(0.05)
    assert world.snapshot().holder == w.PERSON_KEEPS
