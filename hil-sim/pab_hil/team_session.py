"""Multi-target observation in closed loop: three robots' base controllers on one bus, their
observer and wander behaviours, the world, the recorder.

    session = TeamSession("vcan0", Path("out/team"), boards=("r1",))
    session.start()
    ...
    session.close()

On start: the recorder begins the candump log, the three nodes start with empty stores (the names
in `boards` as the emulated board), `pabctl push` sends each its table from
examples/multi-target-observation.toml, and one thread runs the world and publishes every
behaviour's frames at OBSERVER_HZ on a python-can socket, while python-can's notifier hands
each robot the commands its node re-publishes. The nodes exchange their claims (Broadcast of
Local Eligibility) by themselves: the harness never sends one, never arbitrates, never decides
who holds a target.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import can

from . import team as t
from .nodes import EXAMPLES, Nodes, PushResult, push
from .observe import Recorder
from .realtime import make_current_thread_realtime

NETWORK = EXAMPLES / "multi-target-observation.toml"


class TeamError(AssertionError):
    pass


class TeamSession:
    def __init__(self, iface: str, out_dir: Path, world: t.TeamWorld,
                 boards: tuple[str, ...] = (), network: Path = NETWORK) -> None:
        self.iface = iface
        self.out_dir = out_dir
        self.world = world
        self.network = network
        self.log_path = out_dir / "bus.log"
        board_routes = (t.board_routes(t.ROBOTS[boards[0]]) if boards else None)
        self.nodes = Nodes(iface, out_dir, node_ids=t.ROBOTS, boards=boards,
                           board_routes=board_routes)
        self.recorder: Recorder | None = None
        self.pushed: PushResult | None = None  # pabctl push's result, once started
        self.bus: can.BusABC | None = None
        self.notifier: can.Notifier | None = None
        self.lag = 0.0  # s: how late the publishing loop ran at worst
        self.realtime = False  # whether that loop got a real-time scheduling class
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.recorder = Recorder(self.iface, self.log_path)
        self.nodes.start()
        result = self.pushed = push(self.network, self.iface)
        (self.out_dir / "push.txt").write_text(result.output)
        if not result.ok:
            raise TeamError(f"pabctl push failed (status {result.returncode}):\n{result.output}")
        filters = [{"can_id": t.drive_id(robot), "can_mask": 0x7FF, "extended": False}
                   for robot in t.ROBOTS.values()]
        self.bus = can.Bus(interface="socketcan", channel=self.iface, can_filters=filters)
        self.notifier = can.Notifier(self.bus, [self._on_message], timeout=0.1)
        self._thread = threading.Thread(target=self._run, name="team-world", daemon=True)
        self._thread.start()

    def _on_message(self, message: can.Message) -> None:
        robot = message.arbitration_id - 0x300
        command = t.Command.decode(bytes(message.data))
        if command is not None and robot in t.ROBOTS.values():
            self.world.deliver(robot, command)

    def _run(self) -> None:
        # The team's behaviours are other robots' computers: their clock must not wait for the
        # nodes under test (pab_hil.realtime).
        self.realtime = make_current_thread_realtime()
        period = 1.0 / t.OBSERVER_HZ
        next_tick = time.monotonic()
        last = next_tick
        while not self._stop.is_set():
            now = time.monotonic()
            self.world.step(now - last)
            last = now
            for can_id, payload in self.world.frames():
                try:
                    self.bus.send(can.Message(arbitration_id=can_id, is_extended_id=False,
                                              data=payload))
                except can.CanError:
                    pass  # a full queue: the frame is lost, as on a busy bus
            next_tick += period
            self.lag = max(self.lag, time.monotonic() - next_tick)
            delay = next_tick - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)
            else:
                next_tick = time.monotonic()  # late: no burst to catch up

    def kill(self, name: str) -> float:
        """Stops node `name` at once (SIGKILL; the board: QEMU ends) and returns when, on the
        clock of the log's timestamps."""
        at = time.time()
        self.nodes[name].kill()
        return at

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        if self.notifier is not None:
            self.notifier.stop()
        if self.bus is not None:
            self.bus.shutdown()
        self.nodes.stop()
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None
