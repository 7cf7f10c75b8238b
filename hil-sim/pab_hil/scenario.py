"""One closed-loop session on a bus: nodes, their tables, behaviours, the world, the recorder.

    with Session("vcan0", Path("out/run")) as session:
        session.wait_for(lambda: session.phases.current() == "F", 60, "phase F")

On entry: the three `pab-node` processes start with empty stores, `pabctl push` sends each its
table, the behaviours are forked, the recorder starts the candump log and switches the nodes'
diagnostic streams on, and the world begins to move. On exit everything is stopped, the log is
closed and, if asked, the stimulation plot is drawn.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

from . import protocol as p
from .behaviours import BehaviourProcesses, Loss
from .nodes import NODE_IDS, TAKE_AND_RETURN, Nodes, PushResult, push
from . import observe
from .observe import Listening, Observer, Recorder
from .person import TakeAndReturn
from .phases import NAMES, PhaseLog
from .world import HOLDERS, World

DIAGNOSTIC_RATE_HZ = 10


class ScenarioError(AssertionError):
    """The session did not reach what it waited for; the message says what it saw instead."""


class Session:
    def __init__(
        self,
        iface: str,
        out_dir: Path,
        network: Path = TAKE_AND_RETURN,
        person: TakeAndReturn | None = None,
        progress: Callable[[str], None] | None = None,
        behaviours: tuple[str, ...] | None = None,
        boards: tuple[str, ...] = (),
        node_args: dict[str, tuple[str, ...]] | None = None,
        loss: Loss | None = None,
        board_elf: Path | None = None,
        board_boot: "BehindBootloader | None" = None,
        fd: bool = False,
    ) -> None:
        self.iface = iface
        self.out_dir = out_dir
        self.network = network
        self.person = person if person is not None else TakeAndReturn()
        self.progress = progress or (lambda _line: None)
        self.log_path = out_dir / "bus.log"
        self.world = World()
        self.phases = PhaseLog()
        self.nodes = Nodes(iface, out_dir, boards=boards, node_args=node_args,
                           board_elf=board_elf, board_boot=board_boot)
        self.behaviour_names = behaviours  # None: all seven
        self.loss = loss  # behaviour frames dropped at random, if any
        self.behaviours: BehaviourProcesses | None = None
        self.recorder: Recorder | None = None
        self.pushed: PushResult | None = None  # pabctl push's result, once started
        self.fd = fd  # the tables pushed in CAN FD frames (pabctl push --fd)
        self.listening: Listening | None = None
        self.observer = Observer(self.world)
        self._stop = threading.Event()
        self._world_thread: threading.Thread | None = None

    # -- lifecycle ------------------------------------------------------------------------------

    def __enter__(self) -> "Session":
        try:
            self.start()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.world.epoch = time.time()
        # The recorder first, so that the log holds the whole run, the table push included.
        self.recorder = Recorder(self.iface, self.log_path)
        self.nodes.start()
        self.progress(f"nodes started on {self.iface}: " + ", ".join(
            f"{name} (id {node.node_id}, pid {node.pid})" for name, node in self.nodes.by_name.items()
        ))
        result = self.pushed = push(self.network, self.iface, fd=self.fd)
        (self.out_dir / "push.txt").write_text(result.output)
        if not result.ok:
            raise ScenarioError(f"pabctl push failed (status {result.returncode}):\n{result.output}")
        self.progress(f"tables pushed with pabctl push {self.network.name}"
                      + (" --fd" if self.fd else ""))
        self.behaviours = BehaviourProcesses(self.world, self.iface, self.behaviour_names,
                                             loss=self.loss)
        self.world.set_person(self.person)
        self.world.epoch = time.time()  # the scenario's time 0: the behaviours start
        self.behaviours.start()
        self.listening = Listening(self.iface, self.observer)
        self.stream(DIAGNOSTIC_RATE_HZ)
        self._world_thread = threading.Thread(target=self._run_world, name="world", daemon=True)
        self._world_thread.start()
        self.progress("behaviours and world running")

    def close(self) -> None:
        self._stop.set()
        if self._world_thread is not None:
            self._world_thread.join(timeout=5)
        if self.behaviours is not None:
            self.behaviours.stop()
        if self.listening is not None:
            try:
                self.stream(0)
            finally:
                self.listening.close()
                self.listening = None
        self.nodes.stop()
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None
        (self.out_dir / "phases.txt").write_text(self.phase_report() + "\n")

    def _run_world(self) -> None:
        last = self.world.now()
        while not self._stop.wait(0.02):
            now = self.world.now()
            self.world.step(now - last)
            self.phases.update(self.world)
            last = now

    # -- actions --------------------------------------------------------------------------------

    def stream(self, rate_hz: int, node_id: int | None = None) -> None:
        """Switches the diagnostic stream of one node, or of every node of the network."""
        ids = [node_id] if node_id is not None else list(NODE_IDS.values())
        for ident in ids:
            self.listening.send(
                p.frame_id(p.DIAGNOSTIC_CONTROL, p.TOOL, ident), p.diagnostic_control(rate_hz)
            )

    def restart_node(self, name: str) -> None:
        """Kills the node's process (SIGKILL) and starts it again on the same store; resets the
        emulated board (QEMU's system_reset, which keeps its RAM-backed store)."""
        node = self.nodes[name]
        if hasattr(node, "reset"):
            node.reset()
        else:
            node.kill()
            node.start()
        self.stream(DIAGNOSTIC_RATE_HZ, node.node_id)

    def samples(self, node_id: int) -> list[observe.Sample]:
        """The node's diagnostic samples, from the bus log (complete once the session is closed)."""
        return [s for s in observe.samples(self.log_path, self.world.epoch) if s.node == node_id]

    # -- waiting --------------------------------------------------------------------------------

    def wait_for(self, condition: Callable[[], object], timeout: float, what: str) -> float:
        """Polls `condition` until it is true; returns the world time it became true."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return self.world.now()
            time.sleep(0.02)
        raise ScenarioError(f"{what}: not seen within {timeout:.0f} s\n{self.phase_report()}")

    def phase_report(self) -> str:
        s = self.world.snapshot()
        lines = [
            f"phases: {' '.join(self.phases.sequence()) or '(none yet)'}",
            *(f"  {c.time:7.2f} s  {c.phase}  {NAMES[c.phase]}" for c in self.phases.changes()),
            f"world at {s.t:.2f} s: object held by {HOLDERS.get(s.holder, s.holder)}, "
            f"hand closure {s.closure:.2f}, person {'present' if s.face_present else 'away'}",
            f"observer: {self.observer.frames} frames, at worst {self.observer.max_lag * 1000:.0f} ms "
            f"behind the bus; deliveries arm {len(self.world.deliveries.arm)}, "
            f"gaze {len(self.world.deliveries.gaze)}, hand {len(self.world.deliveries.hand)}",
        ]
        return "\n".join(lines)
