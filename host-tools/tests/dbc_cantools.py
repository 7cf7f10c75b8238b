#!/usr/bin/env python3
"""Checks a DBC file written by `pabctl dbc` for examples/take-and-return.toml with cantools.

    python host-tools/tests/dbc_cantools.py target/examples/take-and-return.dbc \
        [target/examples/multi-target-observation.dbc [target/examples/door-dynamics.dbc \
        [target/examples/tour-guide.dbc [target/examples/assembly.dbc \
        [target/examples/sensors.dbc [target/examples/value-ports.dbc \
        [target/examples/take-and-return-fd.dbc]]]]]]]

(sensors.dbc from host-tools/tests/fixtures/sensors.toml).

The expected identifiers and payload bytes are built here from the layout documented in
docs/can-protocol.md, not from pabctl's code: this is what a user decoding a capture relies on.
Exits 0 when every check passes, 1 with the failures listed otherwise (2 if cantools is missing).
"""

import sys

try:
    import cantools
except ImportError as error:  # never skip silently
    print(f"error: cantools is not installed ({error}); run scripts/python-env.sh", file=sys.stderr)
    sys.exit(2)

# docs/can-protocol.md, "Identifiers": priority 28..26, marker 0b10 in 25..24, service 23..16,
# destination 15..8, source 7..0; tool 0, broadcast 0xFF.
TOOL, BROADCAST = 0x00, 0xFF
SERVICES = {  # name: (code, priority)
    "Fault": (0x01, 0),
    "Heartbeat": (0x02, 4),
    "TableStatus": (0x03, 4),
    "Traffic": (0x04, 5),
    "Errors": (0x05, 5),
    "Diagnostic": (0x06, 7),
    "DiagnosticControl": (0x10, 3),
    "TableTransfer": (0x11, 6),
    "TransferStatus": (0x12, 2),
    "ChallengeRequest": (0x13, 3),
    "Challenge": (0x14, 2),
    "TransferOpen": (0x15, 3),
    "Receipt": (0x16, 2),
    "EmergencyStop": (0x00, 0),
    "SchemaAbort": (0x19, 1),
    "SchemaTransfer": (0x1A, 2),
    "SchemaAck": (0x1B, 2),
    "SchemaTransition": (0x1C, 2),
    "SchemaState": (0x1D, 5),
    "IdentityRequest": (0x21, 3),
    "Identity": (0x22, 4),
    "IdentityVersion": (0x23, 4),
    "IdentityBuild": (0x24, 4),
    "IdentityCapacity": (0x25, 4),
    "IdentityFeatures": (0x26, 4),
    "IdentityName": (0x27, 4),
    "Assign": (0x28, 3),
    "Configure": (0x29, 3),
    "ConfigStatus": (0x2A, 2),
    "UpdateTransfer": (0x2B, 6),
    "UpdateStatus": (0x2C, 2),
}
NODES = {"arm": 1, "hand": 2, "gaze": 3}  # examples/take-and-return.toml
OUTPUTS = {"arm_target_out": 0x200, "gaze_target_out": 0x201, "hand_command_out": 0x202}
TOPICS = {
    "object_pos": 0x110,
    "face_pos": 0x111,
    "look_target": 0x112,
    "rest_pose": 0x113,
    "grasp_cmd": 0x120,
    "release_cmd": 0x121,
    "rest_open": 0x122,
    "grasped": 0x130,
}

failures = []

# The six identity frames (docs/can-protocol.md, "Identity and configuration").
IDENTITY = ("Identity", "IdentityVersion", "IdentityBuild", "IdentityCapacity", "IdentityFeatures",
            "IdentityName")


def check(condition, message):
    if not condition:
        failures.append(message)


def frame_id(service, source, destination):
    code, priority = SERVICES[service]
    return priority << 26 | 0b10 << 24 | code << 16 | destination << 8 | source


def main(path):
    db = cantools.database.load_file(path, strict=True)

    # Identifiers and names.
    check(frame_id("Heartbeat", 3, BROADCAST) == 0x1202FF03, "the documented example id")
    expected = {}
    for node, node_id in NODES.items():
        for service in ("Fault", "Heartbeat", "TableStatus", "Traffic", "Errors", "Diagnostic"):
            expected[f"PAB_{service}_{node}"] = (frame_id(service, node_id, BROADCAST), True)
        for service in ("TransferStatus", "Challenge", "Receipt"):
            expected[f"PAB_{service}_{node}"] = (frame_id(service, node_id, TOOL), True)
        for service in ("ChallengeRequest", "TransferOpen", "Assign", "Configure", "IdentityRequest"):
            expected[f"PAB_{service}_{node}"] = (frame_id(service, TOOL, node_id), True)
        # The identity: answers to the tool, and the announcement to all at start-up.
        for service in IDENTITY:
            expected[f"PAB_{service}_{node}"] = (frame_id(service, node_id, TOOL), True)
            expected[f"PAB_{service}_{node}_all"] = (frame_id(service, node_id, BROADCAST), True)
        expected[f"PAB_ConfigStatus_{node}"] = (frame_id("ConfigStatus", node_id, TOOL), True)
        expected[f"PAB_UpdateStatus_{node}"] = (frame_id("UpdateStatus", node_id, TOOL), True)
        expected[f"PAB_DiagnosticControl_{node}"] = (
            frame_id("DiagnosticControl", TOOL, node_id),
            True,
        )
    expected["PAB_DiagnosticControl_all"] = (frame_id("DiagnosticControl", TOOL, BROADCAST), True)
    expected["PAB_IdentityRequest_all"] = (frame_id("IdentityRequest", TOOL, BROADCAST), True)
    for topic, can_id in TOPICS.items():
        expected[topic] = (can_id, False)
    # ISO-TP table transfers: the tool's frames to each node and its flow control back.
    for node, node_id in NODES.items():
        expected[f"PAB_TableTransfer_{node}"] = (frame_id("TableTransfer", TOOL, node_id), True)
        expected[f"PAB_TableTransferFlow_{node}"] = (frame_id("TableTransfer", node_id, TOOL), True)
        # Firmware updates: ISO-TP the same way, on service 0x2B.
        expected[f"PAB_UpdateTransfer_{node}"] = (frame_id("UpdateTransfer", TOOL, node_id), True)
        expected[f"PAB_UpdateTransferFlow_{node}"] = (frame_id("UpdateTransfer", node_id, TOOL), True)
    # The ports that re-publish what they deliver (`republish` in the example).
    for port, can_id in OUTPUTS.items():
        expected[port] = (can_id, False)
    actual = {m.name: (m.frame_id, m.is_extended_frame) for m in db.messages}
    for name, (can_id, extended) in expected.items():
        got = actual.get(name)
        check(got == (can_id, extended), f"{name}: expected id {can_id:#x} extended={extended}, got {got}")
    extra = set(actual) - set(expected)
    check(not extra, f"unexpected messages: {sorted(extra)}")
    check({n.name for n in db.nodes} == {"PABCTL", *NODES}, f"nodes: {[n.name for n in db.nodes]}")

    def decode(name, data, **options):
        message = db.get_message_by_name(name)
        return message, db.decode_message(message.frame_id, bytes(data), **options)

    # A table transfer's first frame to node 1: PCI 0x1 (first frame), length 0x0B5 = 181 bytes,
    # then the image's first bytes; padded to 8 bytes, like every ISO-TP frame of ours.
    message, values = decode("PAB_TableTransfer_arm", [0x10, 0xB5, 0x50, 0x41, 0x42, 0x54, 2, 0])
    check(message.length == 8 and message.senders == ["PABCTL"], f"table transfer: {message}")
    check((str(values["pci_type"]), values["pci_low"], values["data1"]) == ("first frame", 0, 0xB5),
          f"table transfer first frame: {values}")
    _, values = decode("PAB_TableTransferFlow_arm", [0x30, 8, 0, 0xCC, 0xCC, 0xCC, 0xCC, 0xCC])
    check((str(values["pci_type"]), values["pci_low"], values["data1"]) == ("flow control", 0, 8),
          f"table transfer flow control: {values}")
    # A re-published frame: the delivered frame's payload, 8 bytes (the ports' topics' length).
    message, values = decode("arm_target_out", [1, 2, 3, 4, 5, 6, 7, 8])
    check(message.length == 8 and values["data7"] == 8 and message.senders == ["arm"],
          f"arm_target_out: {message.senders} {values}")

    # Heartbeat from node 3: state 1 (operational), uptime 0x123456 s, table version 7.
    data = [1, 0x56, 0x34, 0x12, 7, 0, 0, 0]
    message, values = decode("PAB_Heartbeat_gaze", data)
    check(str(values["state"]) == "operational", f"heartbeat state: {values['state']!r}")
    check(values["uptime"] == 0x123456, f"heartbeat uptime: {values['uptime']}")
    check(values["table_version"] == 7, f"heartbeat version: {values['table_version']}")
    check(message.cycle_time == 1000, f"heartbeat cycle time: {message.cycle_time}")
    encoded = message.encode({"state": 1, "uptime": 0x123456, "table_version": 7})
    check(list(encoded) == data, f"heartbeat encodes to {encoded.hex()}")
    states = {int(k): str(v) for k, v in message.get_signal_by_name("state").choices.items()}
    check(states == {0: "no table", 1: "operational", 2: "fault"}, f"node states: {states}")

    # Fault from node 1: TableRefused (0x0002), 3 occurrences, detail byte 0 = CrcMismatch (0x16).
    _, values = decode("PAB_Fault_arm", [0x02, 0x00, 3, 0x16, 0, 0, 0, 9])
    check(str(values["code"]) == "pushed table refused", f"fault code: {values['code']!r}")
    check(values["count"] == 3 and values["detail0"] == 0x16 and values["detail4"] == 9, f"fault: {values}")
    _, values = decode("PAB_Fault_arm", [0x13, 0x00, 1, 0, 0, 0, 0, 0])
    check(str(values["code"]) == "bus-off or error-passive", f"fault code 0x13: {values['code']!r}")

    # Table status of node 2: CRC 0xDEADBEEF, 177 bytes, 1 port, stored, stream off.
    _, values = decode("PAB_TableStatus_hand", [0xEF, 0xBE, 0xAD, 0xDE, 177, 0, 1, 0b01])
    check(
        (values["crc"], values["image_len"], values["ports"], values["stored"], values["diagnostic"])
        == (0xDEADBEEF, 177, 1, 1, 0),
        f"table status: {values}",
    )

    # Traffic and errors counters.
    _, values = decode("PAB_Traffic_arm", [0x40, 0x42, 0x0F, 0x00, 42, 0, 0, 0])
    check((values["received"], values["delivered"]) == (1_000_000, 42), f"traffic: {values}")
    _, values = decode("PAB_Errors_arm", [5, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF])
    check((values["discarded"], values["errors"]) == (5, 0xFFFFFFFF), f"errors: {values}")

    # Diagnostic sample: port 2, connection 15, active + delivering + end of round, sequence 200,
    # S = 0.5 (2^30 in Q1.31).
    level = (1 << 30).to_bytes(4, "little")
    _, values = decode("PAB_Diagnostic_gaze", [2, 15, 0b1101, 200, *level])
    check(
        (values["port"], values["connection"], values["active"], values["resting"])
        == (2, 15, 1, 0),
        f"diagnostic indices and flags: {values}",
    )
    check(values["delivering"] == 1 and values["end_of_round"] == 1, f"diagnostic flags: {values}")
    check(values["sequence"] == 200, f"diagnostic sequence: {values}")
    check(abs(values["level"] - 0.5) < 1e-9, f"diagnostic level: {values['level']}")
    _, values = decode("PAB_Diagnostic_gaze", [0, 0, 0, 0, *(1 << 31).to_bytes(4, "little")])
    check(abs(values["level"] - 1.0) < 1e-9, f"diagnostic level 1.0: {values['level']}")

    # Diagnostic control to node 2: 20 rounds/s, ports 0 and 2; 4 bytes.
    message, values = decode("PAB_DiagnosticControl_hand", [20, 0, 0b101, 0])
    check(message.length == 4, f"diagnostic control length: {message.length}")
    check((values["rate"], values["ports"]) == (20, 0b101), f"diagnostic control: {values}")
    check(message.senders == ["PABCTL"], f"diagnostic control sender: {message.senders}")

    # Transfer status from node 1: OlderVersion (0x15), running version 9.
    _, values = decode("PAB_TransferStatus_arm", [0x15, 0, 9, 0, 0, 0, 0, 0])
    check(
        str(values["status"]) == "image is not newer than the running table",
        f"transfer status: {values['status']!r}",
    )
    check(values["running_version"] == 9, f"transfer status version: {values}")
    _, values = decode("PAB_TransferStatus_arm", [0x00, 0, 1, 2, 0, 0, 0, 0])
    check(str(values["status"]) == "applied and stored", f"transfer status 0: {values['status']!r}")
    check(values["running_version"] == 0x0201, f"transfer status version: {values}")

    # Update status from node 1 (docs/can-protocol.md, UpdateStatus): Ack, next byte 0x012345,
    # running CRC 0xDEADBEEF.
    message, values = decode("PAB_UpdateStatus_arm", [2, 0x45, 0x23, 0x01, 0xEF, 0xBE, 0xAD, 0xDE])
    check(message.frame_id == 0x0A2C0001, f"update status id: {message.frame_id:#x}")
    check(str(values["status"]) == "chunk written", f"update status: {values['status']!r}")
    check((values["offset"], values["value"]) == (0x012345, 0xDEADBEEF), f"update status: {values}")
    # The first frame of a Chunk to node 1 (1 + 4 + 1024 bytes): PCI first frame.
    _, values = decode("PAB_UpdateTransfer_arm", [0x14, 0x05, 2, 0, 0x04, 0, 0, 0xAA])
    check((str(values["pci_type"]), values["data2"]) == ("first frame", 2), f"update transfer: {values}")

    # A topic: raw bytes; a shorter frame decodes with allow_truncated.
    message, values = decode("object_pos", [1, 2, 3, 4, 5, 6, 7, 8])
    check([values[f"data{i}"] for i in range(8)] == [1, 2, 3, 4, 5, 6, 7, 8], f"topic: {values}")
    check(set(message.receivers) == {"arm", "gaze"}, f"object_pos receivers: {message.receivers}")
    _, values = decode("grasp_cmd", [0xAA, 0xBB], allow_truncated=True)
    check(values == {"data0": 0xAA, "data1": 0xBB}, f"truncated topic: {values}")


def claims(path):
    """The BLE claim messages of examples/multi-target-observation.toml (nodes r1..r3, groups
    observe_t1..observe_t4): docs/can-protocol.md, "Broadcast of Local Eligibility"."""
    db = cantools.database.load_file(path)
    for name, node in {"r1": 1, "r2": 2, "r3": 3}.items():
        message = db.get_message_by_name(f"PAB_Claim_{name}")
        # priority 4, marker 0b10, claim bit 23, 0xFFFF - eligibility (0 here), node id.
        expected = 4 << 26 | 0b10 << 24 | 1 << 23 | 0xFFFF << 7 | node
        check(message.frame_id == expected and message.is_extended_frame,
              f"claim of {name}: id {message.frame_id:#x}, expected {expected:#x}")
        check(message.cycle_time == 100, f"claim of {name}: cycle {message.cycle_time} ms")
        check(sorted(message.receivers) == sorted(n for n in ("r1", "r2", "r3") if n != name),
              f"claim of {name}: receivers {message.receivers}")
    # Node 2 offering 500 for group 1 (observe_t2): payload group, eligibility LE, reserved.
    values = db.get_message_by_name("PAB_Claim_r2").decode(bytes([1, 0xF4, 0x01, 0]))
    check(values == {"Group": 1, "Eligibility": 500, "Reserved": 0}, f"claim payload: {values}")


def gates(path):
    """The Gates message of examples/door-dynamics.toml (the base, node 5, runs group 0 `door` of
    3 behaviours; the head, node 6, runs none): docs/can-protocol.md, "Competitive-dynamics
    gates"."""
    db = cantools.database.load_file(path)
    names = [m.name for m in db.messages if m.name.startswith("PAB_Gates")]
    check(names == ["PAB_Gates_base"], f"gates messages: {names}")
    message = db.get_message_by_name("PAB_Gates_base")
    expected = 3 << 26 | 0b10 << 24 | 0x07 << 16 | BROADCAST << 8 | 5
    check(message.frame_id == expected and message.is_extended_frame,
          f"gates: id {message.frame_id:#x}, expected {expected:#x}")
    check(message.cycle_time == 100, f"gates: cycle {message.cycle_time} ms")
    check(message.length == 8, f"gates: length {message.length}")
    # Group 0, 3 behaviours, search and approach open (bits 0 and 2), the second change.
    values = message.decode(bytes([0, 3, 0b101, 0, 0, 0, 2, 0]))
    check(values == {"group": 0, "behaviours": 3, "gates": 0b101, "changes": 2, "reserved": 0},
          f"gates payload: {values}")


def hbba(path):
    """The HBBA messages of examples/tour-guide.toml (nodes head 1 and base 2, both with filtered
    connections; the intention node at 126): docs/can-protocol.md, "HBBA message filters"."""
    db = cantools.database.load_file(path)
    intention = 126
    desire = db.get_message_by_name("PAB_Desire_PABCTL")
    expected = 4 << 26 | 0b10 << 24 | 0x08 << 16 | BROADCAST << 8 | TOOL
    check(desire.frame_id == expected, f"desire: id {desire.frame_id:#x}, expected {expected:#x}")
    # Class 2 at intensity 3 for 500 ms, the sender's desire 7.
    values = desire.decode(bytes([2, 0, 3, 0, 0xF4, 0x01, 7, 0]))
    check(values == {"class": 2, "reserved": 0, "intensity": 3, "lease": 500, "id": 7},
          f"desire payload: {values}")
    message = db.get_message_by_name("PAB_Intention_PAB_INTENT")
    expected = 4 << 26 | 0b10 << 24 | 0x09 << 16 | BROADCAST << 8 | intention
    check(message.frame_id == expected, f"intention: id {message.frame_id:#x}")
    values = message.decode(bytes([0b101, 0, 0, 0, 1, 0, 0, 0]))
    check(values == {"strategies_low": 0b101, "strategies_high": 1}, f"intention: {values}")
    for name, node in {"head": 1, "base": 2}.items():
        status = db.get_message_by_name(f"PAB_FilterStatus_{name}")
        expected = 4 << 26 | 0b10 << 24 | 0x0A << 16 | BROADCAST << 8 | node
        check(status.frame_id == expected and status.cycle_time == 1000,
              f"filter status of {name}: id {status.frame_id:#x}, cycle {status.cycle_time}")
        values = status.decode(bytes([0xFF, 0, 0x34, 0x12, 3, 1, 1, 0]))
        check((values["profile"], values["sequence"], values["filtered"], values["closed"],
               values["throttled"]) == (255, 0x1234, 3, 1, 1), f"filter status: {values}")
        edge = db.get_message_by_name(f"PAB_Exploitation_{name}")
        expected = 5 << 26 | 0b10 << 24 | 0x0B << 16 | BROADCAST << 8 | node
        check(edge.frame_id == expected and edge.length == 4, f"exploitation of {name}")
        values = edge.decode(bytes([1, 0, 1, 0]))
        check(str(values["delivering"]) == "started delivering" and values["port"] == 1,
              f"exploitation payload: {values}")
        set_ = db.get_message_by_name(f"PAB_FilterSet_{name}")
        expected = 3 << 26 | 0b10 << 24 | 0x18 << 16 | node << 8 | intention
        check(set_.frame_id == expected and set_.length == 6, f"filter set to {name}")
        values = set_.decode(bytes([0, 1, 3, 0, 9, 0]))
        check((values["port"], values["connection"], values["phi"], values["sequence"])
              == (0, 1, 3, 9), f"filter set payload: {values}")
        profile = db.get_message_by_name(f"PAB_FilterProfile_{name}")
        expected = 3 << 26 | 0b10 << 24 | 0x17 << 16 | node << 8 | intention
        check(profile.frame_id == expected and profile.length == 4, f"filter profile to {name}")


def schema(path):
    """The schema server's messages of examples/assembly.toml (node arm, id 10, runs the server):
    docs/can-protocol.md, "Schema server"."""
    db = cantools.database.load_file(path, strict=True)
    arm = 10
    stop = db.get_message_by_name("PAB_EmergencyStop_all")
    check(stop.frame_id == 0x0200FF00 and stop.is_extended_frame and stop.length == 0,
          f"emergency stop to all: id {stop.frame_id:#x}, length {stop.length}")
    check(db.decode_message(stop.frame_id, b"") == {}, "the emergency stop has no signal")
    for name, service, source, destination, length in [
        ("PAB_EmergencyStop_arm", "EmergencyStop", TOOL, arm, 0),
        ("PAB_SchemaAbort_arm", "SchemaAbort", TOOL, arm, 0),
        ("PAB_SchemaAbort_all", "SchemaAbort", TOOL, BROADCAST, 0),
        ("PAB_SchemaAck_arm", "SchemaAck", arm, TOOL, 8),
        ("PAB_SchemaTransition_arm", "SchemaTransition", arm, BROADCAST, 8),
        ("PAB_SchemaState_arm", "SchemaState", arm, BROADCAST, 8),
    ]:
        message = db.get_message_by_name(name)
        expected = frame_id(service, source, destination)
        check(message.frame_id == expected and message.is_extended_frame and message.length == length,
              f"{name}: id {message.frame_id:#x} length {message.length}, expected {expected:#x} {length}")
    for name, source, destination in [
        ("PAB_SchemaTransfer_arm", TOOL, arm),
        ("PAB_SchemaTransferFlow_arm", arm, TOOL),
    ]:
        message = db.get_message_by_name(name)
        expected = frame_id("SchemaTransfer", source, destination)
        check(message.frame_id == expected and message.length == 8,
              f"{name}: id {message.frame_id:#x} length {message.length}, expected {expected:#x} 8")
    # A single frame of 3 bytes: PCI 0x03, then the channel byte and two bytes of the schema.
    values = db.decode_message(frame_id("SchemaTransfer", TOOL, arm), bytes([3, 1, 2, 3, 0xCC, 0xCC, 0xCC, 0xCC]))
    check((str(values["pci_type"]), values["pci_low"], values["data1"]) == ("single frame", 3, 1),
          f"schema transfer single frame: {values}")
    # Schema 0x0102 refused: queue full, on the queue, 8 queued.
    values = db.decode_message(frame_id("SchemaAck", arm, TOOL), bytes([0x09, 0, 2, 1, 8, 0, 0, 0]))
    check(str(values["outcome"]) == "queue full (8): refused, nothing overwritten"
          and str(values["channel"]) == "queue" and values["id"] == 0x0102 and values["queued"] == 8,
          f"schema ack: {values}")
    values = db.decode_message(frame_id("SchemaAck", arm, TOOL), bytes([0x0B, 0xFF, 0xFF, 0xFF, 0, 0, 0, 0]))
    check(str(values["outcome"]) == "message longer than 273 bytes" and str(values["channel"]) == "unreadable"
          and values["id"] == 0xFFFF, f"schema ack, unreadable: {values}")
    # Schema 7 ended by the force limit, recovery 0xFF13 installed (innate), 3 queued.
    values = db.decode_message(frame_id("SchemaTransition", arm, BROADCAST),
                               bytes([7, 0, 0x13, 0xFF, 2, 3, 0, 3]))
    check((values["ended"], values["installed"], str(values["trigger"]), values["detail"],
           str(values["source"]), values["queued"]) == (7, 0xFF13, "safety event", 3, "innate", 3),
          f"schema transition: {values}")
    # Waiting for the queue, from the queue, no fault, armed, gripper closed, 1234 ms.
    message = db.get_message_by_name("PAB_SchemaState_arm")
    values = message.decode(bytes([0x00, 0xFF, 1, 0xFF, 0, 0b11, 0xD2, 0x04]))
    check((values["current"], str(values["source"]), str(values["fault"]), values["armed"],
           values["gripper_closed"], values["elapsed"]) == (0xFF00, "queue", "none", 1, 1, 1234),
          f"schema state: {values}")
    values = message.decode(bytes([5, 0, 2, 4, 1, 0, 0, 0]))
    check(str(values["fault"]) == "watchdog" and str(values["source"]) == "high-priority",
          f"schema state, stopped: {values}")
    check(message.cycle_time == 100, f"schema state cycle time: {message.cycle_time}")
    drive(db)


def pack21(values, flag):
    """docs/can-protocol.md, "The drive's frames": three signed 21-bit values (two's
    complement) in bits 0-20, 21-41, 42-62, the flag in bit 63, little endian."""
    word = sum((v & 0x1FFFFF) << (21 * i) for i, v in enumerate(values)) | (flag << 63)
    return word.to_bytes(8, "little")


def drive(db):
    """The drive's frames of examples/assembly.toml: drive = { setpoint = 0x300, pose = 0x310,
    wrench = 0x320 } (standard ids)."""
    for name, ident in [("Drive_Attractor_arm", 0x300), ("Drive_AttractorRotation_arm", 0x301),
                        ("Drive_Impedance_arm", 0x302), ("Drive_Pose_arm", 0x310),
                        ("Drive_PoseRotation_arm", 0x311), ("Drive_Wrench_arm", 0x320),
                        ("Drive_Torque_arm", 0x321)]:
        message = db.get_message_by_name(name)
        check(message.frame_id == ident and not message.is_extended_frame and message.length == 8,
              f"{name}: id {message.frame_id:#x}")
    values = db.decode_message(0x300, pack21((-100_000, 60_000, -3), 1))
    check((values["x"], values["y"], values["z"], values["gripper_closed"]) == (-100_000, 60_000, -3, 1),
          f"attractor: {values}")
    values = db.decode_message(0x320, pack21((-(1 << 20), (1 << 20) - 1, 7_000), 0))
    check((values["fx"], values["fy"], values["fz"]) == (-(1 << 20), (1 << 20) - 1, 7_000),
          f"wrench at the field's bounds: {values}")
    values = db.decode_message(0x302, (2000).to_bytes(4, "little") + (120).to_bytes(4, "little"))
    check((values["stiffness"], values["damping"]) == (2000, 120), f"impedance: {values}")
    check(db.get_message_by_name("Drive_Attractor_arm").cycle_time == 1, "the attractor every 1 ms")


def field_bytes(raw, offset, size, signed, endian, length=8):
    """A payload whose field carries `raw`, as pab_core::value_port::Field writes and reads it:
    `size` bytes (1, 2 or 4) from byte `offset`, two's complement when signed, in `endian`
    byte order; the other bytes 0."""
    data = bytearray(length)
    data[offset:offset + size] = raw.to_bytes(size, endian, signed=signed)
    return bytes(data)


def sensors(path):
    """The sensor topics of host-tools/tests/fixtures/sensors.toml ([schema.arm.sensors.*],
    node arm): a frame the board reads a raw count from (value_port::Field: offset, size,
    signed, endian) decodes in cantools to raw × the sensor's scale, in its unit."""
    db = cantools.database.load_file(path, strict=True)
    # name: (message, id, extended, length, offset, size, signed, endian, scale, unit)
    table = {
        "gap": ("Sensor_gap_arm", 0x330, False, 2, 0, 2, False, "little", 0.01, "mm"),
        "pressure": ("Sensor_pressure_temperature_arm", 0x331, False, 8, 2, 2, True, "big", 0.5, "kPa"),
        "temperature": ("Sensor_pressure_temperature_arm", 0x331, False, 8, 7, 1, True, "little", 0.25, "degC"),
        "ticks": ("Sensor_ticks_arm", 0x1234567, True, 8, 4, 4, False, "big", 1, None),
        "torque": ("Sensor_torque_arm", 0x332, False, 5, 1, 4, True, "little", 0.001, "N.m"),
    }
    names = sorted(m.name for m in db.messages if m.name.startswith("Sensor_"))
    check(names == sorted({row[0] for row in table.values()}), f"sensor messages: {names}")
    for name, (message_name, ident, extended, length, offset, size, signed, endian, scale, unit) in table.items():
        message = db.get_message_by_name(message_name)
        check((message.frame_id, message.is_extended_frame, message.length) == (ident, extended, length),
              f"{message_name}: id {message.frame_id:#x} extended={message.is_extended_frame} "
              f"length {message.length}")
        check(message.senders == [] or message.senders == ["Vector__XXX"],
              f"{message_name}: the user's frame, no known sender: {message.senders}")
        signal = message.get_signal_by_name(name)
        check(signal.scale == scale and signal.unit == unit and signal.is_signed == signed,
              f"{name}: scale {signal.scale} unit {signal.unit!r} signed {signal.is_signed}")
        bits = 8 * size
        low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
        # The field's bounds and a value whose every byte differs (a byte-order mistake shows).
        for raw in (low, high, 0x12 if size == 1 else int.from_bytes(bytes(range(1, size + 1)), "big")):
            raw = raw if raw <= high else raw - (1 << bits)
            values = db.decode_message(ident, field_bytes(raw, offset, size, signed, endian))
            check(abs(values[name] - raw * scale) <= 1e-9 * max(1, abs(raw * scale)),
                  f"{name}: raw {raw} ({endian} endian at byte {offset}) decodes to {values[name]}, "
                  f"expected {raw * scale}")
    # Two sensors in one frame, each its own field.
    data = bytearray(field_bytes(-300, 2, 2, True, "big"))
    data[7] = (-7).to_bytes(1, "little", signed=True)[0]
    values = db.decode_message(0x331, bytes(data))
    check((values["pressure"], values["temperature"]) == (-150.0, -1.75), f"shared frame: {values}")
    # The plant's range finder at 35 mm: round(35 / 0.01) counts, as sim::schema::range_frame
    # writes it (8 bytes); the network's topic `range` on the same id joins the message.
    values = db.decode_message(0x330, field_bytes(round(35 / 0.01), 0, 2, False, "little"))
    check(abs(values["gap"] - 35.0) < 1e-9, f"range finder frame: {values}")
    receivers = db.get_message_by_name("Sensor_gap_arm").receivers
    check(set(receivers) == {"arm", "eye"}, f"Sensor_gap_arm receivers: {receivers}")
    check(not any(m.name == "range" for m in db.messages), "topic `range` has no second message")


def value_ports(path):
    """examples/value-ports.toml: topics of `length = 2` whose bytes 0-1 are port base.nearest's
    value (u16, little endian), a signal of its own; the port re-publishes on 0x320."""
    db = cantools.database.load_file(path, strict=True)
    for topic, can_id in {"range_left": 0x1A0, "range_front": 0x1A1, "range_right": 0x1A2}.items():
        message = db.get_message_by_name(topic)
        check((message.frame_id, message.length) == (can_id, 2), f"{topic}: {message.frame_id:#x} {message.length}")
        signals = {s.name: (s.start, s.length, s.is_signed, s.byte_order) for s in message.signals}
        check(signals == {"nearest": (0, 16, False, "little_endian")}, f"{topic} signals: {signals}")
    values = db.decode_message(0x1A0, bytes([0xDC, 0x05]))
    check(values == {"nearest": 1500}, f"range_left decodes 1500 mm: {values}")
    message = db.get_message_by_name("base_nearest_out")
    check((message.frame_id, message.length) == (0x320, 2), f"base_nearest_out: {message.frame_id:#x} {message.length}")
    check(db.decode_message(0x320, bytes([0x58, 0x02])) == {"nearest": 600}, "base_nearest_out decodes 600 mm")


def can_fd(path):
    """examples/take-and-return-fd.toml: a CAN FD bus (500 kbit/s, data phase 2 Mbit/s); its
    topics arm_state (0x140, 32 bytes) and hand_skin (0x141, 48 bytes) are CAN FD frames with
    bit-rate switching, the other topics and the protocol's frames classic."""
    db = cantools.database.load_file(path, strict=True)
    check(db.dbc.attributes["BusType"].value == "CAN FD", "BusType is CAN FD")
    for topic, can_id, length in (("arm_state", 0x140, 32), ("hand_skin", 0x141, 48)):
        message = db.get_message_by_name(topic)
        check((message.frame_id, message.length, message.is_fd) == (can_id, length, True),
              f"{topic}: {message.frame_id:#x} {message.length} fd={message.is_fd}")
        payload = bytes(range(length))
        values = db.decode_message(can_id, payload)
        check(values.get(f"data{length - 1}") == length - 1, f"{topic}'s last byte: {values}")
    check(not db.get_message_by_name("object_pos").is_fd, "object_pos is classic")
    heartbeat = db.get_message_by_name("PAB_Heartbeat_arm")
    check(not heartbeat.is_fd and heartbeat.is_extended_frame, "PAB_Heartbeat_arm is classic, extended")


if __name__ == "__main__":
    if len(sys.argv) not in (2, 3, 4, 5, 6, 7, 8, 9):
        print(__doc__, file=sys.stderr)
        sys.exit(2)
    try:
        main(sys.argv[1])
        if len(sys.argv) >= 3:
            claims(sys.argv[2])
        if len(sys.argv) >= 4:
            gates(sys.argv[3])
        if len(sys.argv) >= 5:
            hbba(sys.argv[4])
        if len(sys.argv) >= 6:
            schema(sys.argv[5])
        if len(sys.argv) >= 7:
            sensors(sys.argv[6])
        if len(sys.argv) >= 8:
            value_ports(sys.argv[7])
        if len(sys.argv) == 9:
            can_fd(sys.argv[8])
    except Exception as error:  # a missing message, an undecodable frame: report, with what came before
        failures.append(f"{type(error).__name__}: {error}")
    for failure in failures:
        print(f"FAIL: {failure}", file=sys.stderr)
    if failures:
        print(f"{len(failures)} check(s) failed", file=sys.stderr)
        sys.exit(1)
    print(f"{sys.argv[1]}: cantools {cantools.__version__} decodes every message as documented")
