"""The controller nodes as `pab-node` processes, and `pabctl` for pushing their tables.

Both are the project's own binaries, found in `$PAB_BIN_DIR`, else in the workspace's cargo
target directory (`$CARGO_TARGET_DIR` or `target/`, release profile: the figures are a product's,
not a debug build's). Nothing here imitates them.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from .realtime import keep_softirq_ahead, make_realtime

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"
TAKE_AND_RETURN = EXAMPLES / "take-and-return.toml"

# The network's controller nodes: name -> node id (the [nodes] of the network file).
NODE_IDS = {"arm": 1, "hand": 2, "gaze": 3}

# The HIL nodes beat four times a second, so that `pabctl push` (which waits for the heartbeat
# showing the new table) and `pabctl nodes` answer quickly.
HEARTBEAT_MS = 250


class MissingBinary(RuntimeError):
    pass


def binary(name: str) -> Path:
    """The path of one of the project's binaries, or a MissingBinary that says how to build it."""
    if "PAB_BIN_DIR" in os.environ:
        directory = Path(os.environ["PAB_BIN_DIR"])
    else:
        target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
        directory = target / "release"
    path = directory / name
    if not path.is_file():
        raise MissingBinary(
            f"{path} not found: build it with `cargo build --release -p pab-node -p pabctl` "
            "(pab-node's package holds pab-intent too; or point PAB_BIN_DIR at the directory "
            "that holds pab-node, pab-intent and pabctl)"
        )
    return path


@dataclass
class NodeProcess:
    """One `pab-node` process; its log goes to `<log_dir>/<name>.log`."""

    name: str
    node_id: int | None  # None: started without --node-id (unassigned, unless its store says)
    iface: str
    store: Path
    log_dir: Path
    extra_args: tuple[str, ...] = ()  # more `pab-node` options, e.g. ("--rcvbuf", "16384")
    process: subprocess.Popen | None = None

    def start(self) -> None:
        self.store.mkdir(parents=True, exist_ok=True)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        log = open(self.log_dir / f"{self.name}.log", "ab")
        self.process = subprocess.Popen(
            [
                str(binary("pab-node")),
                "--iface", self.iface,
                *(("--node-id", str(self.node_id)) if self.node_id is not None else ()),
                "--store", str(self.store),
                "--heartbeat-ms", str(HEARTBEAT_MS),
                *self.extra_args,
            ],
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        # A node under test runs as a robot's controller would: real-time, with the kernel's
        # softirq threads ahead of it (pab_hil.realtime).
        if make_realtime(self.process.pid):
            keep_softirq_ahead()
        log.close()
        # A node that cannot start (no interface...) exits at once with status 2: say so here.
        time.sleep(0.2)
        if self.process.poll() is not None:
            raise RuntimeError(
                f"pab-node {self.name} exited with status {self.process.returncode}: "
                + (self.log_dir / f"{self.name}.log").read_text(errors="replace")[-2000:]
            )

    @property
    def pid(self) -> int | None:
        return self.process.pid if self.process else None

    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def kill(self) -> None:
        """SIGKILL, as a power cut would stop a board: no chance to tidy up."""
        if self.running():
            self.process.send_signal(signal.SIGKILL)
            self.process.wait(timeout=10)

    def stop(self) -> None:
        if self.running():
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=5)


class Nodes:
    """The network's nodes, started together, each with its own table store: `pab-node`
    processes, and the emulated board (`pab_hil.board.BoardNode`) for the names in `boards`, with
    `board_routes` as the cangw filters of what reaches it (default: its acceptance filter,
    `board.acceptance`), `board_elf` as its firmware (default: the production build) and
    `board_ahead` whether its QEMU runs ahead of the suite's other work (for a test that times the
    board itself: `pab_hil.board.BOARD_NICENESS_STEP`) and `board_boot` whether `board_elf` is
    its bootloader (`pab_hil.board.BehindBootloader`: the factory image and the key page)."""

    def __init__(self, iface: str, work_dir: Path, node_ids: dict[str, int] = NODE_IDS,
                 boards: tuple[str, ...] = (),
                 node_args: dict[str, tuple[str, ...]] | None = None,
                 board_routes: tuple[str, ...] | None = None,
                 board_elf: Path | None = None, board_ahead: bool = False,
                 board_boot=None) -> None:
        from .board import UART_ENV, BoardNode

        unknown = set(boards) - set(node_ids)
        if unknown:
            raise ValueError(f"no node named {', '.join(sorted(unknown))} in {sorted(node_ids)}")
        if len(boards) > 1 and os.environ.get(UART_ENV):
            raise ValueError("in the micro-VM the host serves one emulated board (one serial "
                             "port): run one node as the board")
        # The stores live in a local temporary directory: a node answers a push only once the
        # table is stored, and a results directory may be a slow network share (the micro-VM's).
        self.store_root = Path(tempfile.mkdtemp(prefix="pab-hil-store-"))
        self.by_name: dict[str, NodeProcess | BoardNode] = {
            name: BoardNode(name, node_id, iface, work_dir / "logs",
                            to_board=board_routes, elf=board_elf, ahead=board_ahead,
                            boot=board_boot)
            if name in boards
            else NodeProcess(name, node_id, iface, self.store_root / name, work_dir / "logs",
                             tuple((node_args or {}).get(name, ())))
            for name, node_id in node_ids.items()
        }

    def __getitem__(self, name: str):
        return self.by_name[name]

    def start(self) -> None:
        _LIVE.add(self)
        for node in self.by_name.values():
            node.start()

    def stop(self) -> None:
        for node in self.by_name.values():
            node.stop()
        shutil.rmtree(self.store_root, ignore_errors=True)
        _LIVE.discard(self)


# Every started `Nodes` not stopped yet. A test that fails between starting its nodes and
# stopping them would otherwise leave them on the bus, where the next test's node of the same id
# answers its transfers twice: one failure becomes a cascade (seen as every later test of a file
# failing with transfer timeouts). conftest stops the leftovers after each test.
_LIVE: set[Nodes] = set()


def stop_leftovers() -> list[str]:
    """Stops every started `Nodes` that was not stopped; returns the names of their nodes."""
    names = []
    for group in list(_LIVE):
        names.extend(f"{name} (id {node.node_id})" for name, node in group.by_name.items()
                     if node.running())
        group.stop()
    return names


# A node's time budget for a transfer (docs/can-protocol.md, "Table transfer"): 1 s, and 10 ms
# for each consecutive frame the image needs (pab_app's TRANSFER_BASE_US, TRANSFER_PER_FRAME_US).
TRANSFER_BASE_S = 1.0
TRANSFER_PER_FRAME_S = 0.010


def transfer_budget(length: int) -> float:
    """s: how long a node gives a transfer of `length` bytes, its first frame to its last."""
    return TRANSFER_BASE_S + TRANSFER_PER_FRAME_S * -(-max(0, length - 6) // 7)


@dataclass
class PushResult:
    returncode: int
    output: str

    @property
    def ok(self) -> bool:
        return self.returncode == 0

    def transfers(self) -> dict[str, tuple[int, float]]:
        """Per node pabctl reached: (bytes, seconds from the first frame to the last), from its
        lines "NAME  node N  LEN bytes in MS ms (F classic CAN frames)  ok: ..."."""
        return {name: (length, seconds) for name, (length, seconds, _, _) in self.pushes().items()}

    def pushes(self) -> dict[str, tuple[int, float, int, str]]:
        """Per node pabctl reached: (bytes, seconds from the first frame to the last, the frames
        it sent, "classic CAN" or "CAN FD")."""
        found = re.finditer(r"^\s*(\S+)\s+node\s+\d+\s+(\d+) bytes in (\d+) ms "
                            r"\((\d+) (classic CAN|CAN FD) frames?\)", self.output, re.MULTILINE)
        return {m.group(1): (int(m.group(2)), int(m.group(3)) / 1000, int(m.group(4)), m.group(5))
                for m in found}


def push(
    network: Path,
    iface: str,
    node: str | None = None,
    table_version: int | None = None,
    timeout: float = 120.0,
    key: Path | None = None,
    fd: bool = False,
) -> PushResult:
    """`pabctl push`: the real path a table takes to a node (ISO-TP, then the node's checks);
    with `key` (a key file), the key holder's authenticated push; with `fd`, in CAN FD frames
    (`--fd`: ISO-TP on CAN FD, 64-byte frames with the bit-rate switch)."""
    command = [str(binary("pabctl")), "push", str(network), "--iface", iface]
    if fd:
        command.append("--fd")
    if node is not None:
        command += ["--node", node]
    if key is not None:
        command += ["--key", str(key)]
    if table_version is not None:
        command += ["--table-version", str(table_version)]
    result = subprocess.run(
        command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=timeout, text=True
    )
    return PushResult(result.returncode, result.stdout)


def pushed_within_budget(bound, pushed: PushResult) -> None:
    """Each node's table transfer in `pushed` (pabctl push), first frame to last, against the
    node's own time budget for it (`transfer_budget`): the product's limit, not an allowance of
    the suite. `bound` is the tests' fixture of that name."""
    transfers = pushed.transfers()
    if not transfers:
        raise AssertionError(f"pabctl push printed no transfer time:\n{pushed.output}")
    for name, (length, seconds) in transfers.items():
        bound(f"{name}'s table transfer ({length} bytes)", seconds, most=transfer_budget(length))


def compile_images(network: Path, output: Path, table_version: int | None = None) -> dict[str, bytes]:
    """`pabctl compile`: each node's table image, by node name."""
    command = [str(binary("pabctl")), "compile", str(network), "--output", str(output)]
    if table_version is not None:
        command += ["--table-version", str(table_version)]
    subprocess.run(command, check=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=60)
    return {path.stem: path.read_bytes() for path in output.glob("*.pab")}
