"""The schema server on the bus (docs/schema-server.md): the arm's node (`pab-node`, the Linux
node's code) runs the schema server of examples/assembly.toml at 200 Hz, the paper's rate;
`pabctl plant` is the robot in front of it (the simulator's plant, in real time); the Python
client `pab_client` sends the paper's program, the file's own schemas (`pabctl sim
--schema-program`).

What is asserted: the six parts go in with exactly the schemas and triggering events the
simulator gives for the same file, and no safety event; an emergency stop frame halts the board
(attractor on the measured pose) within a period; an obstacle on the way raises the force event
and the board stops; a search over a plate without a hole ends by its watchdog. Figures (the stop's
latency, the schema transfer time, the plant's count of inserted parts) go to the test's output
directory. The emergency stop is also run with the arm's node as the boards' firmware on the
emulated Cortex-M4 (`pab_hil.board`), the boards' firmware with the server in it, whose schemas
and drive frames cross its serial line, at 50 Hz (what that line carries: BOARD_PERIOD_S).

The HIL file differs from the example in what a real-time run on the micro-VM needs: a 5 ms
period, a 100 ms overrun bound and 500 ms sensor staleness (the VM's scheduling, not the loop,
decides how late a tick can be), and faster moves (100 mm/s, touch-downs at 10 mm/s) to keep the
run under a minute.
"""

from __future__ import annotations

import contextlib
import csv
import json
import statistics
import subprocess
import time
from pathlib import Path

import can
import pytest

from pab_client import Client, client_filters
from pab_client.client import Refused, Timeout
from pab_client.auth import read_key
from pab_client.schema import Schema
from pab_hil import board, nodes
from pab_hil import protocol as p
from pab_hil.nodes import REPO, binary
from pab_hil.observe import Recorder
from pab_hil.realtime import make_realtime

ASSEMBLY = REPO / "examples" / "assembly.toml"
ARM = 10
# The emulated board's node id: its firmware's build default.
BOARD = 1
PERIOD_S = 0.005
# The emulated board's period: its serial line carries some 700 frames a second each way (docs/mps2-an386.md:
# about 1.4 ms a frame), and the plant publishes four frames a period (pose and
# wrench, two each): at 5 ms that is 800 a second, more than the line, whose queues then grow
# until frames are lost (a schema's ISO-TP frames among them). At 20 ms, 200 a second.
BOARD_PERIOD_S = 0.02
ESTOP_BROADCAST = 0x0200FF00
SETPOINT = 0x300
# s: how long the client waits for each SchemaAck on the reference machine (its default).
ACK_TIMEOUT_S = 1.0
POSE = 0x310

SAFETY_NAMES = {0: "estop", 1: "stale", 2: "limit", 3: "force", 4: "watchdog", 5: "overrun",
                6: "implausible", 7: "joint", 8: "speed"}
AXES = ("x", "y", "z", "rx", "ry", "rz")


def hil_network(tmp_path: Path, name: str, extra: str = "", changes=()) -> Path:
    """examples/assembly.toml for a real-time run on the micro-VM, with `changes` (old, new) and
    `extra` appended."""
    text = ASSEMBLY.read_text()
    base = [
        ("period_ms = 1\n", "period_ms = 5\noverrun_ms = 100\nstale_ms = 500\n"),
        ("\nspeed_mm_s = 50\n", "\nspeed_mm_s = 100\n"),
        ("touch_speed_mm_s = 5\n", "touch_speed_mm_s = 10\n"),
    ]
    for old, new in [*base, *changes]:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path = tmp_path / f"{name}.toml"
    path.write_text(text + extra)
    return path


def simulate(network: Path, out: Path) -> tuple[list[dict], list[tuple[str, str, str]]]:
    """`pabctl sim`: the file's program (name and schema per call) and the simulated trace
    (schema, source, event per installed schema)."""
    program, trace = out / "program.json", out / "sim-trace.csv"
    subprocess.run([str(binary("pabctl")), "sim", str(network), "--schema-program", str(program),
                    "--schema-trace", str(trace)], check=True, stdout=subprocess.PIPE,
                   stderr=subprocess.STDOUT, timeout=300)
    with trace.open() as f:
        rows = [(r["schema"], r["source"], r["event"]) for r in csv.DictReader(f)]
    return json.loads(program.read_text()), rows


def measure_name(m) -> str:
    kind = type(m).__name__
    if kind == "Contact":
        return "contact"
    if kind == "Sensor":
        return f"sensor.{m.index}"
    return f"{kind.lower()}.{AXES[m.axis]}"


def event_name(event) -> str:
    """A reaction's event as the simulator's trace names it."""
    kind = type(event).__name__
    if kind in ("Above", "Below"):
        return f"{kind.lower()}:{measure_name(event.measure)}"
    return {"OneShot": "one-shot", "Done": "done", "Elapsed": "elapsed",
            "QueueReady": "queue-ready"}[kind]


def schema_name(sid: int, names: dict[int, str]) -> str:
    if sid == 0xFF00:
        return "wait-queue"
    if sid == 0xFF01:
        return "wait-high-priority"
    if 0xFF10 <= sid < 0xFF10 + len(SAFETY_NAMES):
        return f"safety:{SAFETY_NAMES[sid - 0xFF10]}"
    return names[sid]


def live_rows(client: Client, calls: list[dict]) -> list[tuple[str, str, str]]:
    """The node's transitions, named as the simulator's trace names them."""
    names = {c["schema"]["id"]: c["name"] for c in calls}
    reactions = {c["schema"]["id"]: Schema.from_json(c["schema"]).reactions for c in calls}
    rows = []
    for t in client.transitions:
        trigger = t.trigger.name
        if trigger == "Safety":
            event = f"safety:{SAFETY_NAMES[t.detail]}"
        elif trigger == "HighPriority":
            event = "high-priority"
        elif trigger == "Abort":
            event = "abort"
        elif t.ended == 0xFF00:
            event = "queue-ready"
        elif t.ended in reactions:
            event = event_name(reactions[t.ended][t.detail].event)
        else:
            event = "one-shot"
        source = {"Innate": "innate", "Queue": "queue", "HighPriority": "high-priority"}[
            t.source.name]
        rows.append((schema_name(t.installed, names), source, event))
    return rows


class Rig:
    """The arm's node with the file's table, the plant and a client, on the HIL bus. The node is
    `pab-node` as node `ARM`, or with `board` the emulated Cortex-M4 (`pab_hil.board`), whose
    firmware runs the same server, built as node 1 (`PAB_NODE_ID`'s default)."""

    def __init__(self, iface: str, network: Path, out: Path, bound, board: bool = False,
                 key: Path | None = None, board_elf: Path | None = None) -> None:
        """`key`: a key file (`pabctl keygen`); the node (`pab-node --key`) then takes its table
        and its schemas from the key holder only, and the push and the client use it.
        `board_elf`: the board's firmware (default: the production build). What is started is
        stopped by `close`, or at once if the rig fails to come up."""
        self.iface, self.network, self.out = iface, network, out
        self.node_id = node_id = BOARD if board else ARM
        self._stack = contextlib.ExitStack()
        try:
            self._start(bound, board, key, board_elf)
        except BaseException:
            self._stack.close()
            raise

    def _start(self, bound, board: bool, key: Path | None, board_elf: Path | None) -> None:
        iface, network, out, node_id = self.iface, self.network, self.out, self.node_id
        stack = self._stack
        self.nodes = nodes.Nodes(iface, out, node_ids={"arm": node_id},
                                 boards=("arm",) if board else (),
                                 node_args={"arm": ("--key", str(key))} if key else None,
                                 board_elf=board_elf, board_ahead=True)
        stack.callback(self.nodes.stop)
        self.nodes.start()
        pushed = nodes.push(network, iface, node="arm", key=key)
        assert pushed.ok, pushed.output
        nodes.pushed_within_budget(bound, pushed)
        # Every frame goes to the candump log, from a process of its own; the client's socket
        # takes only the node's answers (its filters), so that neither falls behind the other's
        # share of the bus (the plant alone sends 800 frames a second).
        self.recorder = Recorder(iface, out / "bus.log")
        stack.callback(self.recorder.close)
        # The plant is the robot's drive, a device of its own: real-time, as the node.
        self.plant = subprocess.Popen(
            [str(binary("pabctl")), "plant", str(network), "--iface", iface,
             "--log", str(out / "plant.csv")],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        stack.callback(lambda: self.plant.poll() is None and self.stop_plant())
        make_realtime(self.plant.pid)
        self.bus = can.Bus(interface="socketcan", channel=iface, can_filters=client_filters(node_id))
        stack.callback(self.bus.shutdown)
        self.client = Client(self.bus, node_id, key=read_key(key) if key else None)
        stack.callback(self.client.close)
        state = self.client.status(timeout=10)
        deadline = time.monotonic() + 10
        while not (state and state.armed) and time.monotonic() < deadline:
            state = self.client.status(timeout=1)
        assert state is not None and state.armed, f"the board never armed: {state}"

    def stop_plant(self) -> str:
        self.plant.terminate()
        output, _ = self.plant.communicate(timeout=30)
        (self.out / "plant.txt").write_text(output)
        return output

    def frames(self) -> list[can.Message]:
        """Every frame on the bus so far, with the kernel's timestamps: ends the recording."""
        self.recorder.close()
        return list(can.CanutilsLogReader(str(self.out / "bus.log")))

    def close(self) -> None:
        """Stops what `__init__` started, the last first; each step runs whatever the others
        raise (the nodes are stopped even if the plant would not end)."""
        self._stack.close()


def send_program(client: Client, calls: list[dict], timeout: float,
                 ack_timeout: float = 1.0) -> list[float]:
    """Installs each call's schema as the queue takes it, waiting up to `ack_timeout` s for each
    SchemaAck; returns the transfer times (first frame to SchemaAck) of the first eight, which
    find room at once. Stops sending on a safety event, also while it waits for room: a stopped
    server's queue no longer drains (on a slow machine the obstacle's stop came while the ninth
    schema waited, which then waited its whole `timeout` for room that never came)."""
    def stopped() -> bool:
        return any(t.trigger.name == "Safety" for t in client.transitions)

    transfers = []
    for index, call in enumerate(calls):
        if stopped():
            break
        schema = Schema.from_json(call["schema"])
        if index < 8:
            # The queue (8 deep) has room for the first eight: one transfer each, no wait.
            started = time.monotonic()
            client.install(schema, timeout=ack_timeout)
            transfers.append(time.monotonic() - started)
            continue
        deadline = time.monotonic() + timeout
        while True:
            try:
                client.install_when_room(schema, timeout=min(1.0, timeout),
                                         ack_timeout=ack_timeout)
                break
            except Timeout as no_room:
                # No room (its cause the node's refusal); any other timeout is a failure.
                if not isinstance(no_room.__cause__, Refused):
                    raise
                if stopped():
                    return transfers
                if time.monotonic() >= deadline:
                    raise
    return transfers


def test_six_parts_assembled_over_the_bus_as_simulated_on_a_keyed_node(iface, tmp_path, out_dir,
                                                                        bound, machine):
    """The node has a key: its table comes by `pabctl push --key`, and every schema of the
    program goes as the key holder's (a challenge, a TransferOpen, the message and its MAC, a
    Receipt that verifies), as on a robot whose schemas must come from its own client only."""
    network = hil_network(tmp_path, "assembly-hil")
    calls, simulated = simulate(network, out_dir)
    key = tmp_path / "arm.key"
    subprocess.run([str(binary("pabctl")), "keygen", "-o", str(key)], check=True,
                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    rig = Rig(iface, network, out_dir, bound, key=key)
    ack_timeout = machine.allow(ACK_TIMEOUT_S)
    try:
        transfers = send_program(rig.client, calls, timeout=120, ack_timeout=ack_timeout)
        ended = rig.client.wait_finished(calls[-1]["schema"]["id"], timeout=180)
        time.sleep(0.5)
        summary = rig.stop_plant()
        rows = live_rows(rig.client, calls)
    finally:
        rig.close()
    (out_dir / "live-trace.json").write_text(json.dumps(rows, indent=1))
    figures = {
        "schema_transfer_ms": {"median": 1000 * statistics.median(transfers),
                               "max": 1000 * max(transfers), "count": len(transfers)},
        "plant": summary.strip(),
    }
    (out_dir / "figures.json").write_text(json.dumps(figures, indent=1))
    bound("slowest schema transfer, first frame to SchemaAck", max(transfers), most=ack_timeout)
    assert ended.trigger.name == "Reaction", ended
    assert rows == simulated
    assert not any(event.startswith("safety:") for _, _, event in rows)
    assert "parts inserted: 6 of 6" in summary, summary


def emergency_stop(rig: Rig, calls: list[dict], ack_timeout: float = 1.0,
                   period_s: float = PERIOD_S) -> dict:
    """A move, stopped after 0.5 s by an emergency stop frame to every node: asserts that the
    board halts and waits for the high-priority channel, and returns the latencies (ms) from the
    stop frame to the fault transition and to the halted set-point, as the bus shows them, and
    the move's transfer time (first ISO-TP frame to SchemaAck)."""
    # The first move, 117 mm at 100 mm/s: stopped after 0.5 s.
    transfers = send_program(rig.client, calls[:1], timeout=10, ack_timeout=ack_timeout)
    rig.client.wait_started(calls[0]["schema"]["id"], timeout=5)
    time.sleep(0.5)
    rig.client.estop(broadcast=True)
    ended = rig.client.wait_finished(calls[0]["schema"]["id"], timeout=5)
    time.sleep(0.3)
    state = rig.client.status(timeout=2)
    frames = rig.frames()
    assert ended.safety is not None and ended.safety.name == "EmergencyStop", ended
    assert state.fault is not None and state.fault.name == "EmergencyStop"
    assert state.current == 0xFF01
    stop = next(m for m in frames if m.is_extended_id and m.arbitration_id == ESTOP_BROADCAST)
    after = [m for m in frames if m.timestamp >= stop.timestamp]
    transition_id = p.frame_id(p.SCHEMA_TRANSITION, rig.node_id, p.BROADCAST)
    transition = next(m for m in after if m.arbitration_id == transition_id and m.data[4] == 2)
    # The halted set-point: the first attractor frame after the stop that is on a pose the node
    # measured, the gripper flag aside; every attractor frame after it is the same. A pose the
    # node measured: one published since the stop or in the 100 ms before it (the plant publishes
    # every period; a node in an emulated machine, or behind the board's serial line, may be some
    # frames behind the bus).
    def same(attractor: bytes, pose: bytes) -> bool:
        return attractor[:7] == pose[:7] and (attractor[7] & 0x7F) == (pose[7] & 0x7F)

    poses = [bytes(m.data) for m in frames if m.timestamp >= stop.timestamp - 0.1
             and m.timestamp < stop.timestamp and m.arbitration_id == POSE
             and not m.is_extended_id]
    halted = None
    for m in after:
        if m.arbitration_id == POSE and not m.is_extended_id:
            poses.append(bytes(m.data))
        elif m.arbitration_id == SETPOINT and not m.is_extended_id:
            if any(same(bytes(m.data), pose) for pose in poses):
                halted = m
                break
    held = [bytes(m.data) for m in after if m.arbitration_id == SETPOINT
            and not m.is_extended_id and halted is not None and m.timestamp >= halted.timestamp]
    assert halted is not None, "no attractor frame on the measured pose after the stop"
    assert len(set(held)) == 1, "the attractor moved after the halt"
    # Halted in the tick that raised the fault: by the first set-point sent after the transition,
    # however late the bus saw both (the board's serial line delays them alike).
    first = next(m for m in after if m.arbitration_id == SETPOINT and not m.is_extended_id
                 and m.timestamp >= transition.timestamp)
    assert halted.timestamp <= first.timestamp, "the set-point halted after the fault's tick"
    return {"transition_ms": 1000 * (transition.timestamp - stop.timestamp),
            "halted_setpoint_ms": 1000 * (halted.timestamp - stop.timestamp),
            "period_ms": 1000 * period_s, "schema_transfer_ms": 1000 * transfers[0]}


def test_an_emergency_stop_frame_halts_the_board_within_a_period(iface, tmp_path, out_dir, bound,
                                                                 machine):
    network = hil_network(tmp_path, "estop-hil")
    calls, _ = simulate(network, out_dir)
    rig = Rig(iface, network, out_dir, bound)
    try:
        latency = emergency_stop(rig, calls, ack_timeout=machine.allow(ACK_TIMEOUT_S))
    finally:
        rig.close()
    (out_dir / "figures.json").write_text(json.dumps(latency, indent=1))
    # Within one period of the loop, plus what the micro-VM's scheduler adds to a wake-up (10 ms
    # on the reference machine).
    bound("the stop frame to the halted set-point", latency["halted_setpoint_ms"] / 1000,
          most=PERIOD_S + machine.allow(0.010), detail=latency)


def test_an_emergency_stop_frame_halts_the_emulated_board_within_a_period(iface, tmp_path,
                                                                          out_dir, bound, machine):
    """The same stop with the arm's node as the boards' firmware on the emulated Cortex-M4
    (pab-fw-an386 in QEMU, on the bus through SLCAN, slcand and cangw), whose firmware has the
    schema server, as the NUCLEO-G474RE's: the server, its schemas over ISO-TP and its drive
    frames all cross the serial line."""
    network = hil_network(tmp_path, "estop-board-hil",
                          changes=[("id = 10\n", f"id = {BOARD}\n"),
                                   ("period_ms = 5\n", f"period_ms = {round(1000 * BOARD_PERIOD_S)}\n")])
    calls, _ = simulate(network, out_dir)
    rig = Rig(iface, network, out_dir, bound, board=True)
    board = rig.nodes["arm"]
    # The schema's ISO-TP frames and their flow control cross the serial line (docs/mps2-an386.md:
    # about 1.4 ms a frame each way, more on a loaded host).
    ack_timeout = machine.board_allow(5.0, board)
    try:
        latency = emergency_stop(rig, calls, ack_timeout=ack_timeout, period_s=BOARD_PERIOD_S)
    finally:
        rig.close()
    assert board.line_losses() == 0, board.statistics
    (out_dir / "figures.json").write_text(json.dumps(latency, indent=1))
    # Halted in the fault's tick is asserted above; from the bus, the stop also waits behind the
    # frames queued on the serial line to the board (the plant's pose and wrench, about 1.4 ms a
    # frame on the host's QEMU, docs/mps2-an386.md), and the halted set-point behind those
    # queued from it: measured 9.5 to 18 ms on an idle 2-core host, 40 ms allowed there.
    bound("the stop frame to the board's halted set-point", latency["halted_setpoint_ms"] / 1000,
          most=BOARD_PERIOD_S + machine.board_allow(0.040, board), detail=latency)
    bound("the board's schema transfer, first frame to SchemaAck",
          latency["schema_transfer_ms"] / 1000, most=ack_timeout)


def test_an_obstacle_raises_the_force_event_and_the_board_stops(iface, tmp_path, out_dir, bound,
                                                                machine):
    network = hil_network(tmp_path, "obstacle-hil",
                          extra="\n[[plant.obstacles]]\nmin_mm = [-110, -10, 0]\n"
                                "max_mm = [-90, 10, 60]\n")
    calls, simulated = simulate(network, out_dir)
    rig = Rig(iface, network, out_dir, bound)
    try:
        send_program(rig.client, calls[:9], timeout=60, ack_timeout=machine.allow(ACK_TIMEOUT_S))
        deadline = time.monotonic() + 60
        while not any(t.trigger.name == "Safety" for t in rig.client.transitions):
            assert time.monotonic() < deadline, "no safety event"
            time.sleep(0.1)
        time.sleep(0.5)
        rows = live_rows(rig.client, calls)
        summary = rig.stop_plant()
    finally:
        rig.close()
    safety = [r for r in rows if r[2].startswith("safety:")]
    assert safety == [("safety:force", "innate", "safety:force")], rows
    assert ("safety:force", "innate", "safety:force") in simulated
    # The same schemas as the simulator up to the stop.
    assert rows == simulated[:len(rows)], (rows, simulated)
    assert "parts inserted: 0 of 6" in summary


def test_a_search_over_a_plate_without_a_hole_ends_by_its_watchdog(iface, tmp_path, out_dir,
                                                                   bound, machine):
    network = hil_network(tmp_path, "no-hole-hil", changes=[
        ("search_radius_mm = 1\n", "search_radius_mm = 0.2\n"),
    ])
    text = network.read_text()
    start = text.index("holes_mm = [")
    end = text.index("]]", start) + 2
    network.write_text(text[:start] + "holes_mm = []" + text[end:])
    calls, _ = simulate(network, out_dir)
    rig = Rig(iface, network, out_dir, bound)
    try:
        send_program(rig.client, calls[:9], timeout=60, ack_timeout=machine.allow(ACK_TIMEOUT_S))
        search = calls[6]["schema"]["id"]
        ended = rig.client.wait_finished(search, timeout=60)
    finally:
        rig.close()
    assert calls[6]["name"] == "blind_search()"
    assert ended.safety is not None and ended.safety.name == "Watchdog", ended


# The save test: rounds of two pushes; the board's server period (ms) and the tick gap (ms) above
# which it raises the overrun; the bus time around the second push's answer in which an overrun is
# the save's. The answer leaves once the save has ended, and the tick the stalled erase delayed
# runs between the erase and the image's programming: its overrun came 0 to 15 ms before the
# answer (the two share the serial line, so they may also cross). Why a period of 10 ms: a stall
# of S ms puts a gap of S to S + period between two ticks, so a bound under the single-bank erase's
# 22 ms catches every stalled save whatever its phase, and at 20 ms it leaves 10 ms to the host's
# jitter. (At a 20 ms period and a 25 ms bound, where the gap had to pass 25 ms, 2 and 1 of 4
# second saves raised it in two runs, and CI's run failed on it.)
SAVE_ROUNDS = 4
SAVE_PERIOD_MS = 10
SAVE_OVERRUN_MS = 20
SAVE_WINDOW_BEFORE_S = 0.1
SAVE_WINDOW_AFTER_S = 0.02


def saves_while_the_server_ticks(iface, tmp_path, out_dir, bound, elf) -> dict:
    """The emulated board runs the server every SAVE_PERIOD_MS with an overrun bound of
    SAVE_OVERRUN_MS (a tick 10 ms late); in each of SAVE_ROUNDS rounds, two tables are pushed one
    after the other. Why two: a pushed table restarts the server, and the first push's save may
    start before the new server's first tick, which has no previous tick to be late against; the
    node saves at most once a second, so the second table's save comes a second after the
    first's, while its server has been ticking (its waiting schema, the set-point held) for most
    of that second. `pabctl push` returns once the table is stored.

    Returns the overruns the second saves raised (those from SAVE_WINDOW_BEFORE_S before to
    SAVE_WINDOW_AFTER_S after the second push's answer on the bus) and all of them. Why not all:
    the emulated board's clock is the host's, and the host now and then holds its QEMU for longer
    than the bound's margin (QEMU's I/O thread moving a burst of the serial line's bytes, the
    scheduler): in 4 runs of the dual-bank test, 1 overrun came that way, during a transfer, a
    second away from the saves."""
    network = hil_network(tmp_path, "save-board-hil", changes=[
        ("id = 10\n", f"id = {BOARD}\n"),
        ("period_ms = 5\n", f"period_ms = {SAVE_PERIOD_MS}\n"),
        ("overrun_ms = 100\n", f"overrun_ms = {SAVE_OVERRUN_MS}\n"),
    ])
    rig = Rig(iface, network, out_dir, bound, board=True, board_elf=elf)
    arm = rig.nodes["arm"]
    version = 1
    try:
        for _ in range(SAVE_ROUNDS):
            # Past the rate limit of the save before: the first push's save starts at once.
            time.sleep(1.2)
            for _ in range(2):
                version += 1
                pushed = nodes.push(network, iface, node="arm", table_version=version)
                assert pushed.ok, pushed.output
        time.sleep(0.5)
        frames = rig.frames()
    finally:
        rig.close()
    transition = p.frame_id(p.SCHEMA_TRANSITION, rig.node_id, p.BROADCAST)
    overruns = [m.timestamp for m in frames if m.arbitration_id == transition
                and m.data[4] == 2 and m.data[5] == 5]
    answers = [m.timestamp for m in frames
               if (ident := p.FrameId.decode(m.arbitration_id, m.is_extended_id)) is not None
               and ident.source == rig.node_id and ident.service == p.TRANSFER_STATUS]
    assert len(answers) == 2 * SAVE_ROUNDS, f"{len(answers)} transfer answers on the bus"
    second = answers[1::2]
    at_saves = [t for t in overruns
                if any(end - SAVE_WINDOW_BEFORE_S <= t <= end + SAVE_WINDOW_AFTER_S for end in second)]
    start = answers[0] - 1.2
    return {
        "overruns_at_the_second_saves": len(at_saves),
        "overruns": [round(t - start, 3) for t in overruns],
        "second_saves_answered": [round(t - start, 3) for t in second],
        "overrun_ms": SAVE_OVERRUN_MS,
        "period_ms": SAVE_PERIOD_MS,
        "saves": 2 * SAVE_ROUNDS,
        "line_losses": arm.line_losses(),
    }


def test_a_table_saved_while_the_emulated_board_runs_its_server_raises_no_overrun(
        iface, tmp_path, out_dir, bound, figures):
    found = saves_while_the_server_ticks(iface, tmp_path, out_dir, bound, None)
    figures("save-while-serving-dual-bank", found)
    assert found["line_losses"] == 0, found
    assert found["overruns_at_the_second_saves"] == 0, found


def test_the_same_saves_on_the_single_bank_layout_raise_the_overrun(iface, tmp_path, out_dir,
                                                                    bound, figures):
    """The control: the single-bank test build's erase stalls the CPU for 22 ms, so the gap
    between the ticks before and after it is 22 to 32 ms, above the 20 ms bound at every save (4 of 4
    second saves in each of four runs)."""
    found = saves_while_the_server_ticks(iface, tmp_path, out_dir, bound,
                                         board.single_bank_firmware())
    figures("save-while-serving-single-bank", found)
    assert found["line_losses"] == 0, found
    assert found["overruns_at_the_second_saves"] > 0, found
