"""Nodes that say who they are, and node ids set over the bus: a `pab-node` started without an id
is listed by `pabctl nodes --json` with its uid and `node_id` null; `pabctl assign` gives it an
id, which it keeps across a restart; and `pabctl push` refuses, before any transfer frame, a
table the node cannot load."""

from __future__ import annotations

import json
import subprocess
import threading
import time

import can

from pab_hil import protocol
from pab_hil.nodes import NodeProcess, binary


def pabctl(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([str(binary("pabctl")), *args], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True, timeout=timeout)


def listed(iface: str) -> list[dict]:
    result = pabctl("nodes", "--iface", iface, "--listen", "1.5", "--json")
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_an_unassigned_node_is_listed_by_uid_assigned_an_id_and_keeps_it(iface, tmp_path):
    node = NodeProcess("spare", None, iface, tmp_path / "spare", tmp_path / "logs")
    node.start()
    try:
        found = listed(iface)
        assert len(found) == 1, found
        spare = found[0]
        assert spare["node_id"] is None and 128 <= spare["id"] <= 254, spare
        assert spare["state"] is None, "an unassigned node sends no heartbeat"
        assert spare["firmware"]["name"] == "pab-node"
        assert len(spare["uid"]) == 16 and spare["uid"] == (tmp_path / "spare" / "uid").read_text().strip()
        assert {"ble", "dynamics", "filters", "schema", "fd"} <= set(spare["features"]), spare
        assert spare["keyed"] is False and spare["protocol"] == 1
        uid = spare["uid"]

        assigned = pabctl("assign", "--iface", iface, "--uid", uid, "--node-id", "9")
        assert assigned.returncode == 0, assigned.stderr
        assert "node id 9 stored and in force" in assigned.stdout, assigned.stdout
        found = listed(iface)
        assert [(n["node_id"], n["uid"]) for n in found] == [(9, uid)], found
        assert found[0]["state"] == "no table", found

        # The id is kept in the store: after a restart the node is node 9 again, same uid.
        node.stop()
        node.start()
        found = listed(iface)
        assert [(n["node_id"], n["uid"]) for n in found] == [(9, uid)], found

        # A uid nobody has, and an id another node answers to, are refused before anything is
        # sent (exit 4, one line saying why).
        nobody = pabctl("assign", "--iface", iface, "--uid", "0" * 16, "--node-id", "10")
        assert nobody.returncode == 4 and "no node with uid" in nobody.stderr, nobody.stderr
        taken = pabctl("assign", "--iface", iface, "--uid", uid, "--node-id", "9")
        assert taken.returncode == 0, taken.stderr  # its own id: allowed, nothing changes
        # pab-node's bit rate is its interface's: `pabctl config` says so.
        config = pabctl("config", "--iface", iface, "--node", "9", "--bitrate", "250")
        assert config.returncode == 4 and "interface" in config.stderr, config
    finally:
        node.stop()


# Five ports on one node: more than a board takes (4).
WIDE = "[nodes.wide]\nid = 9\n" + "".join(
    f'[topics.t{i}]\ncan_id = {0x100 + i}\n[ports."wide.p{i}"]\n'
    f'[connections.C{i}]\ntopic = "t{i}"\nport = "wide.p{i}"\nst = 1.0\ntc = 1.0\n'
    for i in range(5))


def test_a_table_a_node_cannot_load_is_refused_before_any_transfer_frame(iface, tmp_path):
    network = tmp_path / "wide.toml"
    network.write_text(WIDE)
    node = NodeProcess("wide", 9, iface, tmp_path / "wide", tmp_path / "logs",
                       extra_args=("--capacity", "board"))
    node.start()
    transfers: list[can.Message] = []
    stop = threading.Event()

    def record() -> None:
        with can.Bus(interface="socketcan", channel=iface) as bus:
            while not stop.is_set():
                message = bus.recv(0.1)
                if (message is not None and message.is_extended_id
                        and (message.arbitration_id >> 16) & 0xFF == protocol.TABLE_TRANSFER):
                    transfers.append(message)

    recorder = threading.Thread(target=record)
    recorder.start()
    try:
        time.sleep(0.3)
        pushed = pabctl("push", str(network), "--iface", iface)
        assert pushed.returncode == 4, pushed.stdout + pushed.stderr
        assert "not sent: the table has 5 ports, the node takes at most 4" in pushed.stdout, \
            pushed.stdout
        time.sleep(0.3)
    finally:
        stop.set()
        recorder.join()
        node.stop()
    assert transfers == [], f"{len(transfers)} TableTransfer frames on the bus"


def test_the_emulated_board_keeps_an_assigned_id_and_a_new_bit_rate_across_a_reset(iface,
                                                                                    out_dir):
    """The emulated Cortex-M4 (pab-fw-an386's identity build, compiled as node 1) given id 7 and 250 kbit/s over
    the bus: both stored in its configuration page, in force after QEMU's system_reset (a board
    reset: the RAM-backed flash is kept). Its bridge carries frames to node 1 and to node 7."""
    from pab_hil.board import BoardNode, acceptance, identity_firmware

    routes = (*acceptance(1), "82000700:8380FF00")  # and our frames to node 7
    # The log in the results directory: the board's QEMU may run on the micro-VM's host, which
    # sees that directory and not the VM's temporary ones. The identity test build: the
    # production firmware has no identity yet (it does not fit 64 KiB with it).
    board = BoardNode("board", 1, iface, out_dir, to_board=routes, elf=identity_firmware())
    board.start()
    try:
        found = listed(iface)
        assert [n["node_id"] for n in found] == [1], found
        identity = found[0]
        assert identity["firmware"]["name"] == "fw-an386", identity
        assert identity["bitrate_kbps"] == 500 and identity["capacity"]["ports"] == 4, identity
        uid = identity["uid"]

        config = pabctl("config", "--iface", iface, "--node", "1", "--bitrate", "250")
        assert config.returncode == 0, config.stderr
        assert "250 kbit/s stored" in config.stdout, config.stdout
        assigned = pabctl("assign", "--iface", iface, "--uid", uid, "--node-id", "7")
        assert assigned.returncode == 0, assigned.stderr
        assert "node id 7 stored and in force" in assigned.stdout, assigned.stdout
        found = listed(iface)
        assert [(n["node_id"], n["bitrate_kbps"]) for n in found] == [(7, 500)], found

        board.reset()
        deadline = time.monotonic() + 30
        while True:
            found = listed(iface)
            if found or time.monotonic() > deadline:
                break
        assert [(n["node_id"], n["uid"], n["bitrate_kbps"]) for n in found] == [(7, uid, 250)], \
            found
        # The new rate runs on trial until the board hears a frame (these requests), then stays.
        time.sleep(5.5)
        found = listed(iface)
        assert [(n["node_id"], n["bitrate_kbps"], n["bitrate_trial"]) for n in found] == \
            [(7, 250, False)], found
    finally:
        board.stop()
