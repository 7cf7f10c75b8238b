"""Take and Return on a CAN FD bus: `vcan1` (MTU 72, beside the classic `vcan0`), the three
controller nodes as `pab-node`s, their tables pushed in CAN FD frames (`pabctl push --fd`: ISO-TP
on CAN FD, 64-byte frames with the bit-rate switch), the scenario's phases and end as on classic
CAN; and the same tables pushed in classic and in CAN FD frames on that bus, their frames and
times (the figure `push-classic-vs-fd`), with a table of some 5 KB beside them."""

from __future__ import annotations

import statistics
from pathlib import Path

from pab_hil import analysis, protocol as p
from pab_hil.nodes import NODE_IDS, TAKE_AND_RETURN, Nodes, push, pushed_within_budget
from pab_hil.observe import Recorder
from pab_hil.person import TakeAndReturn
from pab_hil.scenario import Session

from test_take_and_return import arm_latency, latency_figure, run_a_to_f, within_bounds


def fd_frames(length: int) -> int:
    """The frames of a CAN FD push of `length` bytes at TX_DL 64: the First Frame carries 62
    bytes (58 with the 32-bit length of a message above 4095 bytes), each Consecutive Frame 63."""
    first = 62 if length <= 4095 else 58
    return 1 + -(-(length - first) // 63)


def classic_frames(length: int) -> int:
    """The frames of a classic push of `length` bytes: 6 in the First Frame (2 with the 32-bit
    length), 7 in each Consecutive Frame."""
    first = 6 if length <= 4095 else 2
    return 1 + -(-(length - first) // 7)


def large_network(directory: Path) -> Path:
    """A network whose arm table is some 5 KB (8 ports of 32 connections in priority order): a
    transfer longer than 4095 bytes, with the 32-bit length of ISO 15765-2:2016 on both kinds of
    frame, and long enough for its time to show more than the machine's scheduling."""
    lines = ["[nodes.arm]", "id = 1", ""]
    for port in range(8):
        lines += [f'[ports."arm.p{port}"]', ""]
        for k in range(32):
            i = port * 32 + k
            lines += [f"[topics.t{i}]", f"can_id = {0x100 + i}", "", f"[connections.C{i}]",
                      f'topic = "t{i}"', f'port = "arm.p{port}"', "st = 0.5", "tc = 1.0"]
            if k:
                above = " | ".join(f"C{port * 32 + j}" for j in range(k))
                lines.append(f'rule = "C{i} & !({above})"')
            lines.append("")
    path = directory / "large.toml"
    path.write_text("\n".join(lines))
    return path


def transfer_frames(messages, node_id: int):
    """The table transfer's frames to `node_id` (the tool's) and from it (its flow controls),
    from a candump log."""
    to_node = p.frame_id(p.TABLE_TRANSFER, p.TOOL, node_id)
    from_node = p.frame_id(p.TABLE_TRANSFER, node_id, p.TOOL)
    sent = [m for m in messages if m.is_extended_id and m.arbitration_id == to_node]
    answers = [m for m in messages if m.is_extended_id and m.arbitration_id == from_node]
    return sent, answers


def test_take_and_return_on_can_fd_with_the_tables_pushed_in_can_fd_frames(
        fd_iface, out_dir, bound, figures):
    person = TakeAndReturn()
    session = Session(fd_iface, out_dir, person=person, fd=True)
    try:
        session.start()
        pushed_within_budget(bound, session.pushed)
        pushes = session.pushed.pushes()
        assert set(pushes) == set(NODE_IDS), session.pushed.output
        for name, (length, _, frames, framing) in pushes.items():
            assert (framing, frames) == ("CAN FD", fd_frames(length)), (name, pushes[name])
        run_a_to_f(session, person)
    finally:
        session.close()

    # The capture (candump -L: `ID##FDATA` for a CAN FD frame, F its flags nibble: 1 the
    # bit-rate switch, 2 ESI, 4 FDF, which Linux 6.1 sets, so `##5`): every frame of each
    # transfer is CAN FD with the bit-rate switch, the tool's 64 bytes but the last, and so is
    # every flow control the node answered with.
    messages = analysis.read_log(session.log_path)
    for name, node_id in NODE_IDS.items():
        sent, answers = transfer_frames(messages, node_id)
        length = pushes[name][0]
        assert len(sent) == fd_frames(length), (name, len(sent))
        assert all(m.is_fd and m.bitrate_switch for m in sent + answers), name
        assert all(m.dlc == 64 for m in sent[:-1]), [m.dlc for m in sent]
        assert answers and all(m.data[0] == 0x30 for m in answers), answers
    fd_lines = [line for line in session.log_path.read_text().splitlines() if "##" in line]
    assert fd_lines and all(int(line.split("##")[1][0], 16) & 1 for line in fd_lines), fd_lines[:3]
    latency = arm_latency(session)
    figures("latency-behaviour-to-arm-can-fd", latency_figure(latency))
    figures("take-and-return-can-fd", {
        "phases": "".join(session.phases.sequence()),
        "table_bytes": sum(length for length, *_ in pushes.values()),
        "push_frames": sum(frames for _, _, frames, _ in pushes.values()),
    })
    # Against the CAN FD network's bounds (500 kbit/s, 2 Mbit/s data phase): the same nodes and
    # topics, and two CAN FD topics the scenario does not send.
    figures("take-and-return-can-fd-timed-bus",
            within_bounds(TAKE_AND_RETURN.with_name("take-and-return-fd.toml"), session, out_dir))


ROUNDS = 3


def test_the_same_tables_pushed_in_classic_and_in_can_fd_frames(
        fd_iface, out_dir, tmp_path, bound, figures):
    """On the CAN FD bus, the nodes take a push in either kind of frame and answer in its kind;
    each round pushes the Take and Return tables classic, then CAN FD (a new version each time,
    the same rules), and the figure is each node's frames and median transfer time; then the
    same for a table of some 5 KB to the arm node."""
    group = Nodes(fd_iface, out_dir)
    recorder = Recorder(fd_iface, out_dir / "bus.log")
    large = large_network(tmp_path)
    results = {"classic CAN": [], "CAN FD": []}
    large_results = {"classic CAN": [], "CAN FD": []}
    try:
        group.start()
        version = 1
        for network, node, into in ((TAKE_AND_RETURN, None, results),
                                    (large, "arm", large_results)):
            for _ in range(ROUNDS):
                for fd in (False, True):
                    result = push(network, fd_iface, node=node, table_version=version, fd=fd)
                    assert result.ok, result.output
                    pushed_within_budget(bound, result)
                    into["CAN FD" if fd else "classic CAN"].append(result.pushes())
                    version += 1
    finally:
        group.stop()
        recorder.close()

    messages = analysis.read_log(out_dir / "bus.log")
    figure = {}
    for name, node_id in NODE_IDS.items():
        sent, answers = transfer_frames(messages, node_id)
        length = results["classic CAN"][0][name][0]
        large_length = large_results["classic CAN"][0]["arm"][0] if name == "arm" else 0
        classic = [m for m in sent if not m.is_fd]
        fd = [m for m in sent if m.is_fd]
        # Each push in its own kind, each answered in its kind (a classic flow control to a
        # classic push, a CAN FD one with the bit-rate switch to a CAN FD push).
        expected = [classic_frames(length), fd_frames(length)]
        if large_length:
            assert large_length > 4095, large_length
            expected = [e + classic_frames(large_length) * (i == 0) + fd_frames(large_length) * i
                        for i, e in enumerate(expected)]
        assert len(classic) == ROUNDS * expected[0], (name, len(classic))
        assert len(fd) == ROUNDS * expected[1] and all(m.bitrate_switch for m in fd), name
        assert any(not m.is_fd for m in answers) and any(m.is_fd for m in answers), name
        assert all(m.bitrate_switch for m in answers if m.is_fd), name
        figure[name] = summary(results, name)
        for framing, rounds in results.items():
            assert all(r[name][3] == framing and r[name][0] == length for r in rounds), rounds
    totals = {f"all_{key}": sum(values[key] for values in figure.values())
              for key in ("bytes", "classic_frames", "classic_ms", "fd_frames", "fd_ms")}
    figure["large"] = summary(large_results, "arm")
    figures("push-classic-vs-fd", totals | {
        f"{name}_{key}": value for name, values in figure.items() for key, value in values.items()
    })


def summary(results, name: str) -> dict:
    """A node's pushes of one table: its bytes, and per kind of frame the frames and the median
    transfer time (ms, first frame to last)."""
    return {
        "bytes": results["classic CAN"][0][name][0],
        "classic_frames": results["classic CAN"][0][name][2],
        "classic_ms": round(1000 * statistics.median(r[name][1] for r in results["classic CAN"])),
        "fd_frames": results["CAN FD"][0][name][2],
        "fd_ms": round(1000 * statistics.median(r[name][1] for r in results["CAN FD"])),
    }
