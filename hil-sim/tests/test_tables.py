"""Tables on a running system: a new table pushed during the run takes effect without restarting
any node; a corrupted one is refused and the old behaviour goes on; a restarted node comes back
with its stored table."""

from __future__ import annotations

import math

from pab_hil import nodes, transfer
from pab_hil.nodes import NODE_IDS, TAKE_AND_RETURN
from pab_hil.person import TakeAndReturn
from pab_hil.phases import driver

ARM = NODE_IDS["arm"]

# Version 2 of the arm's rules: while idle the arm points where the eyes look (Look Around's
# targets, a new connection C17) instead of resting (C14 switched off).
POINTING = """
[connections.C17]
topic = "look_target"
port = "arm.target"
st = 0.5
tc = 3.0
rule = "!(C1 | C2 | C6 | C7)"
"""


def pointing_network(tmp_path):
    text = TAKE_AND_RETURN.read_text()
    old_rule = 'rule = "!(C1 | C2 | C6 | C7)"'
    assert text.count(old_rule) == 1
    text = text.replace(old_rule, 'rule = "false"') + POINTING
    path = tmp_path / "take-and-return-pointing.toml"
    path.write_text(text)
    return path


def nobody_comes():
    return TakeAndReturn(show_at=math.inf)


def test_new_table_takes_effect_without_restart_and_a_corrupted_one_is_refused(session_for, tmp_path,
                                                                              bound):
    session = session_for(nobody_comes())
    session.wait_for(lambda: driver(session.world, "arm") == "rest-arm", 30, "the arm resting (A)")
    pids = {name: node.pid for name, node in session.nodes.by_name.items()}
    before = session.observer.node(ARM)
    assert before.heartbeat.table_version == 1

    pushed = nodes.push(pointing_network(tmp_path), session.iface, node="arm", table_version=2)
    assert pushed.ok, pushed.output
    nodes.pushed_within_budget(bound, pushed)
    session.wait_for(lambda: driver(session.world, "arm") == "look-around", 15,
                     "the arm following Look Around (the new rules)")
    assert driver(session.world, "gaze", within=1.5) == "look-around"
    assert {name: node.pid for name, node in session.nodes.by_name.items()} == pids
    assert all(node.running() for node in session.nodes.by_name.values())
    session.wait_for(lambda: session.observer.node(ARM).heartbeat.table_version == 2, 5,
                     "the arm's heartbeat showing version 2")
    new_crc = session.observer.node(ARM).table.crc
    assert new_crc != before.table.crc

    # Version 3, one byte flipped in the table body, sent by python can-isotp: refused on CRC.
    images = nodes.compile_images(TAKE_AND_RETURN, tmp_path / "v3", table_version=3)
    corrupted = bytearray(images["arm"])
    corrupted[-1] ^= 0x40
    transfers = len(session.observer.node(ARM).transfers)
    transfer.send_image(session.iface, ARM, bytes(corrupted))
    session.wait_for(lambda: len(session.observer.node(ARM).transfers) > transfers, 5,
                     "the arm's TransferStatus")
    verdict = session.observer.node(ARM).transfers[-1][1]
    assert verdict.status == "CrcMismatch", verdict
    assert verdict.version == 2, verdict
    refused_at = session.world.now()
    # The old behaviour goes on: version 2 running, the arm still pointing with Look Around.
    session.wait_for(lambda: session.world.now() > refused_at + 2.5, 5, "2.5 s more")
    assert driver(session.world, "arm", within=1.5) == "look-around"
    view = session.observer.node(ARM)
    assert view.heartbeat.table_version == 2 and view.table.crc == new_crc
    assert {name: node.pid for name, node in session.nodes.by_name.items()} == pids

    # The same image intact, by the same third-party ISO-TP stack: accepted (an interop check).
    transfer.send_image(session.iface, ARM, images["arm"])
    session.wait_for(lambda: len(session.observer.node(ARM).transfers) > transfers + 1, 5,
                     "the arm's TransferStatus for the intact image")
    verdict = session.observer.node(ARM).transfers[-1][1]
    assert verdict.status == "Applied" and verdict.version == 3, verdict
    session.wait_for(lambda: driver(session.world, "arm") == "rest-arm", 15,
                     "the arm resting again (version 3 is the original network)")


def test_restarted_node_comes_back_with_its_stored_table(session_for):
    session = session_for(nobody_comes())
    session.wait_for(lambda: driver(session.world, "arm") == "rest-arm", 30, "the arm resting (A)")
    before = session.observer.node(ARM)
    assert before.table.stored, "the pushed table should be stored"
    old_pid = session.nodes["arm"].pid

    session.restart_node("arm")
    restarted_at = session.world.now()
    assert session.nodes["arm"].pid != old_pid

    def fresh_heartbeat():
        view = session.observer.node(ARM)
        return view.heartbeat_time > restarted_at and view.heartbeat.uptime_s <= 2

    session.wait_for(fresh_heartbeat, 5, "a heartbeat from the restarted arm node")
    session.wait_for(lambda: session.observer.node(ARM).heartbeat_time > restarted_at + 0.3, 5,
                     "the heartbeat group after the restart")
    after = session.observer.node(ARM)
    assert after.heartbeat.state == "operational"
    assert after.heartbeat.table_version == before.heartbeat.table_version
    assert after.table.crc == before.table.crc and after.table.stored
    # And it arbitrates again: Rest Arm drives the arm through the restarted node.
    session.wait_for(
        lambda: any(d.time > restarted_at for d in session.world.deliveries.arm[-5:])
        and driver(session.world, "arm") == "rest-arm",
        10,
        "the restarted arm node delivering Rest Arm's frames",
    )
