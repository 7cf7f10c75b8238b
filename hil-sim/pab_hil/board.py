"""The emulated Cortex-M4 board (`pab-fw-an386` in QEMU's `mps2-an386`) as a node on the bus.

The board has no CAN controller: its UART0 speaks SLCAN (Lawicel's serial-line CAN), and standard
Linux parts make that a SocketCAN interface on the bus:

    QEMU's UART0 --serial line--> slcand + the kernel's slcan driver --> slcan interface
                                   cangw (can-gw): slcan interface <-> vcan0, both ways

The serial line is either a pseudo-terminal of a QEMU started here (`LocalQemu`: a workstation
with vcan, the way docs/hil.md runs it by hand), or the micro-VM's second serial port, whose other
end is a QEMU started on the micro-VM's host (`RemoteQemu`, served by `HostBoards`). The second is
how the suite runs in the micro-VM: qemu-system-arm nested inside the emulated x86 guest handles
one received byte per QEMU main-loop iteration and took 100-130 ms per SLCAN frame there, far too
slow for a closed loop; on the host it takes about 1.4 ms. Nothing in the bridge is imitated: the
guest's serial port is QEMU's 16550, `slcand` and `cangw` are can-utils', the drivers the kernel's.

Nothing here arbitrates: the board runs `pab-app`, the same application as `pab-node`.
"""

from __future__ import annotations

import os
import re
import select
import shutil
import signal
import socket
import subprocess
import tempfile
import termios
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path

from .nodes import REPO, MissingBinary

FIRMWARE = "pab-fw-an386"
TARGET = "thumbv7em-none-eabihf"
QEMU = "qemu-system-arm"
# Serial speed set on the line (the firmware's UART runs at the same; a pseudo-terminal ignores it).
BAUD = 115200
# SLCAN's bit rate command: S6 = 500 kbit/s, the G474's rate (the emulated link has no bit timing).
SLCAN_BITRATE = "6"
# Environment of a suite running in the micro-VM: the serial ports whose other ends are on the host.
UART_ENV = "PAB_HIL_BOARD_UART"
CONTROL_ENV = "PAB_HIL_BOARD_CONTROL"
START_TIMEOUT_S = 30.0
# A key page image (`pabctl keypage KEY -o FILE`) to plant at the board's key page: the board then
# runs keyed (docs/keys.md). Unset: an unkeyed board, as before.
KEY_PAGE_ENV = "PAB_KEY_PAGE"
KEY_PAGE_ADDRESS = 0x0004_E000
# What reaches a board: its CAN acceptance filter, as cangw routes from the bus to the serial
# line, one route per filter. The serial line is the bottleneck: QEMU's model of the board's UART
# takes one byte per main-loop iteration (about 50 us on an idle host, far more on a loaded one),
# and a frame is some 25 bytes, about 700 frames a second; the line's queue (the slcan
# interface's) holds `LINE_QUEUE` frames, and cangw drops what does not fit. So only what the
# board acts on crosses it, as a CAN controller's acceptance filter would pass on a robot: every
# frame outside our identifier space (the topics: `topics`, default all of them), the claims of
# Broadcast of Local Eligibility, our frames addressed to the board, and our broadcasts but the
# reports (services 0x01-0x06: faults, heartbeat group, diagnostic stream), which no node acts on
# and which are three quarters of Take and Return's traffic. Our frames addressed to other nodes
# or to the tool (another node's table transfer, its answers) stay off the line.
#
# cangw's format: `id:mask` passes when id & mask match, `id~mask` when they differ; the mask
# holds CAN_EFF_FLAG (0x80000000), so a route tells 29-bit frames from 11-bit ones. The routes are
# disjoint: a frame that passed two would be delivered twice.
ALL_TOPICS = ("82000000~83000000",)  # every 11-bit frame, and every 29-bit one not ours
# Claims (docs/can-protocol.md, "Broadcast of Local Eligibility"): bit 23 set, any priority.
CLAIMS = "82800000:83800000"


def acceptance(node_id: int, topics: tuple[str, ...] = ALL_TOPICS) -> tuple[str, ...]:
    """The cangw filters of what reaches board `node_id` (see above): `topics`, the claims, our
    frames to the board, and our broadcasts of the emergency stop (service 0x00), the Gates
    (0x07) and every service from 0x08 on (ranges of services a mask can select: 0x08-0x0F,
    0x10-0x1F, 0x20-0x3F, 0x40-0x7F; the claims hold 0x80 and up)."""
    if not 1 <= node_id <= 127:
        raise ValueError(f"node {node_id}: nodes are 1..=127")
    ours = [f"8200{node_id:02X}00:8380FF00"]  # to the board: any service below the claims
    for service, mask in ((0x00, 0xFF), (0x07, 0xFF), (0x08, 0xF8), (0x10, 0xF0), (0x20, 0xE0),
                          (0x40, 0xC0)):
        ours.append(f"82{service:02X}FF00:83{mask:02X}FF00")
    return (*topics, CLAIMS, *ours)


# Frames the slcan interface queues for the line (the kernel's default is 10): a burst (an ISO-TP
# block of 8 and the frames around it) waits instead of being dropped by cangw. At about 1.4 ms
# a frame, 256 frames are 0.36 s of the line: a delay the tests would see, never a silent loss.
LINE_QUEUE = 256


class BoardError(RuntimeError):
    pass


def firmware() -> Path:
    """The board firmware's ELF (the `firmware` profile's build; the schema server is in it), or
    a MissingBinary saying how to build it."""
    target = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target"))
    if "PAB_BOARD_ELF" in os.environ:
        path = Path(os.environ["PAB_BOARD_ELF"])
        build = "(PAB_BOARD_ELF names it)"
    else:
        path = target / TARGET / "firmware" / FIRMWARE
        build = (f"cargo build --profile firmware -p {FIRMWARE} --target {TARGET}` (or point "
                 f"PAB_BOARD_ELF at the ELF")
    if not path.is_file():
        raise MissingBinary(f"{path} not found: build it with `{build}`")
    return path


def test_build(feature: str) -> Path:
    """The board's firmware built with the test feature `feature`, which hil-sim/run-hil builds
    and keeps in target/hil-board; or a MissingBinary saying how to build it."""
    elf = REPO / "target" / "hil-board" / f"{FIRMWARE}-{feature}"
    if not elf.is_file():
        raise MissingBinary(
            f"{elf} is missing: hil-sim/run-hil builds it (cargo build --profile firmware -p "
            f"{FIRMWARE} --target {TARGET} --bin {FIRMWARE} --features {feature}, then a copy of "
            f"the ELF there)")
    return elf


def single_bank_firmware() -> Path:
    """The test build with the flash model of the G474 in single-bank mode (feature
    `single-bank`: erases and programs stall the CPU, the modelled CAN controller keeps three
    frames meanwhile)."""
    return test_build("single-bank")


def identity_firmware() -> Path:
    """The test build with identity and configuration over the bus (feature `identity`:
    identity answers, the node id and bit rate kept in the configuration page). Not the flashed
    build: with every mechanism it does not fit the 64 KiB of flash (docs/footprint.md)."""
    return test_build("identity")


#: How much further ahead of the suite's other work (the micro-VM's QEMU, the nodes, run-hil's
#: own niceness) the board's QEMU runs when a test times the board itself (`ahead`). The schema
#: server's tests time its ticks to the millisecond; on a real rig it has a CPU of its own. Here
#: it shares two cores with the micro-VM, whose TCG threads are busy (docs/testing.md): at the
#: same niceness a waking board could wait a scheduler slice behind them, and its ticks came 25 ms
#: late at random instants in some runs (an overrun the tests rightly count). Not for every test:
#: ahead, the board takes CPU from the VM in turn, where the multi-target test times its nodes.
BOARD_NICENESS_STEP = 5


def _board_first() -> None:
    """In the board QEMU's child process: lowers its niceness by BOARD_NICENESS_STEP below the
    suite's, where this process may (root or CAP_SYS_NICE); otherwise keeps the suite's."""
    try:
        os.nice(-BOARD_NICENESS_STEP)
    except OSError:
        pass


@dataclass(frozen=True)
class BehindBootloader:
    """A board behind its bootloader (firmware/boot/mps2-an386): QEMU runs the bootloader's ELF,
    which installs `factory` (the application's raw binary, planted at FACTORY_ADDRESS) into its
    active partition at the first boot, as a probe would flash it; `key_page` (`pabctl keypage
    --update-key`) holds the update key the bootloader checks images against."""
    factory: Path
    key_page: Path


#: Where the bootloader finds the factory image (pab_boot_an386::layout::FACTORY).
FACTORY_ADDRESS = 0x0010_0000


def qemu_command(elf: Path, serial: str, monitor: Path,
                 boot: BehindBootloader | None = None) -> list[str]:
    """QEMU's command line for the board: UART0 on `serial` (a QEMU -serial value), the human
    monitor on the unix socket `monitor` (for system_reset), semihosting (the log, on stderr),
    and the key page of $PAB_KEY_PAGE if set. With `boot`, `elf` is the bootloader, and the
    factory image and the key page are planted for it (QEMU's loader, again at every system
    reset: the bootloader installs the factory image only into an empty active partition)."""
    command = [
        QEMU, "-M", "mps2-an386", "-display", "none", "-no-user-config", "-nodefaults",
        "-semihosting-config", "enable=on,target=native",
        "-serial", serial,
        "-monitor", f"unix:{monitor},server=on,wait=off", "-nic", "none",
        "-kernel", str(elf),
    ]
    if boot is None:
        return command + key_page_arguments()
    for path in (boot.factory, boot.key_page):
        if not path.is_file():
            raise BoardError(f"{path}: no such file")
    return command + [
        "-device", f"loader,file={boot.factory},addr={FACTORY_ADDRESS:#x},force-raw=on",
        "-device", f"loader,file={boot.key_page},addr={KEY_PAGE_ADDRESS:#x},force-raw=on",
    ]


def key_page_arguments() -> list[str]:
    """QEMU's loader for the key page named by $PAB_KEY_PAGE (re-planted at every system reset,
    which a key page does not mind), or nothing when it is unset."""
    page = os.environ.get(KEY_PAGE_ENV)
    if not page:
        return []
    if not Path(page).is_file():
        raise BoardError(f"{KEY_PAGE_ENV}={page}: no such file (pabctl keypage KEY -o FILE)")
    return ["-device", f"loader,file={page},addr={KEY_PAGE_ADDRESS:#x},force-raw=on"]


def monitor_command(monitor: Path, command: str, timeout: float = 5.0) -> str:
    """Sends one command to QEMU's human monitor on `monitor`; returns what it printed."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.settimeout(timeout)
        sock.connect(str(monitor))
        received = b""
        # The banner and the prompt first, then the command, then the next prompt.
        while b"(qemu)" not in received:
            received += sock.recv(4096)
        sock.sendall(command.encode() + b"\n")
        answer = b""
        while answer.count(b"(qemu)") < 1:
            chunk = sock.recv(4096)
            if not chunk:
                break
            answer += chunk
        return answer.decode(errors="replace")


class LocalQemu:
    """The board's QEMU on this machine; its UART0 is a pseudo-terminal here."""

    def __init__(self, elf: Path, log: Path, ahead: bool = False,
                 boot: BehindBootloader | None = None) -> None:
        self.elf = elf
        self.log = log
        self.ahead = ahead
        self.boot = boot
        self.dir = Path(tempfile.mkdtemp(prefix="pab-board-"))
        self.monitor = self.dir / "monitor.sock"
        self.process: subprocess.Popen | None = None

    def start(self) -> str:
        """Starts QEMU; returns the pseudo-terminal of UART0."""
        if shutil.which(QEMU) is None:
            raise BoardError(f"{QEMU} is missing (Debian: apt-get install qemu-system-arm)")
        self.log.parent.mkdir(parents=True, exist_ok=True)
        with open(self.log, "ab") as log:
            self.process = subprocess.Popen(
                qemu_command(self.elf, "pty", self.monitor, self.boot),
                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log,
                preexec_fn=_board_first if self.ahead else None,
            )
        # QEMU names the terminal on stdout: "char device redirected to /dev/pts/3 (label serial0)".
        assert self.process.stdout is not None
        ready, _, _ = select.select([self.process.stdout], [], [], 10.0)
        line = self.process.stdout.readline().decode(errors="replace") if ready else ""
        found = re.search(r"(/dev/pts/\d+)", line)
        if found is None:
            self.stop()
            raise BoardError(f"{QEMU} did not name its pseudo-terminal (it said {line!r}); "
                             f"its log: {self.log}")
        return found.group(1)

    @property
    def pid(self) -> int | None:
        return self.process.pid if self.process else None

    def running(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def reset(self) -> None:
        """QEMU's system_reset: the board reboots; the RAM-backed table store is kept."""
        monitor_command(self.monitor, "system_reset")

    def stop(self) -> None:
        if self.running():
            self.process.terminate()
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=5)
        shutil.rmtree(self.dir, ignore_errors=True)


class RemoteQemu:
    """The board's QEMU on the micro-VM's host (see `HostBoards`). UART0 is this machine's serial
    port `uart` (/dev/ttyS1); requests go over the serial port `control` (/dev/ttyS2), one line
    each way: `start ELF LOG [ahead] [boot FACTORY KEYPAGE]` -> `ok PID`, `reset` -> `ok`, `stop`
    -> `ok`, or `error WHY` (`ahead`: the board's QEMU runs BOARD_NICENESS_STEP ahead of the
    suite; `boot`: ELF is the bootloader, with the factory image and key page of
    `BehindBootloader`)."""

    def __init__(self, elf: Path, log: Path, uart: str, control: str, ahead: bool = False,
                 boot: BehindBootloader | None = None) -> None:
        self.elf = elf
        self.log = log
        self.ahead = ahead
        self.boot = boot
        self.uart = uart
        self.control = control
        self._pid: int | None = None

    def _request(self, line: str, timeout: float = 20.0) -> str:
        fd = os.open(self.control, os.O_RDWR | os.O_NOCTTY)
        try:
            tty.setraw(fd)
            termios.tcflush(fd, termios.TCIOFLUSH)
            os.write(fd, line.encode() + b"\n")
            answer = b""
            deadline = time.monotonic() + timeout
            while not answer.endswith(b"\n"):
                left = deadline - time.monotonic()
                ready, _, _ = select.select([fd], [], [], max(0.0, left))
                if not ready:
                    raise BoardError(f"no answer from the board's host to {line.split()[0]!r} "
                                     f"within {timeout:.0f} s (on {self.control})")
                answer += os.read(fd, 256)
        finally:
            os.close(fd)
        text = answer.decode(errors="replace").strip()
        if not text.startswith("ok"):
            raise BoardError(f"the board's host refused {line.split()[0]!r}: {text}")
        return text[2:].strip()

    def start(self) -> str:
        self.log.parent.mkdir(parents=True, exist_ok=True)
        request = f"start {self.elf} {self.log}" + (" ahead" if self.ahead else "")
        if self.boot is not None:
            request += f" boot {self.boot.factory} {self.boot.key_page}"
        self._pid = int(self._request(request) or 0) or None
        return self.uart

    @property
    def pid(self) -> int | None:
        return self._pid

    def running(self) -> bool:
        return self._pid is not None

    def reset(self) -> None:
        self._request("reset")

    def stop(self) -> None:
        if self._pid is not None:
            self._request("stop")
            self._pid = None


def qemu_here_or_on_host(elf: Path, log: Path, ahead: bool = False,
                         boot: BehindBootloader | None = None) -> LocalQemu | RemoteQemu:
    """RemoteQemu when the suite runs in the micro-VM with the host's board service, else local.
    `ahead`: the board's QEMU runs BOARD_NICENESS_STEP ahead of the suite's other work; `boot`:
    `elf` is the bootloader (`BehindBootloader`)."""
    uart, control = os.environ.get(UART_ENV), os.environ.get(CONTROL_ENV)
    if uart and control:
        return RemoteQemu(elf, log, uart, control, ahead, boot)
    return LocalQemu(elf, log, ahead, boot)


def _run(command: list[str]) -> None:
    result = subprocess.run(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if result.returncode != 0:
        raise BoardError(f"`{' '.join(command)}` failed (status {result.returncode}): "
                         f"{result.stdout.strip()}")


@dataclass
class BoardNode:
    """One node as the emulated board, bridged to `iface`; the same interface as `NodeProcess`.

    `start` boots the board, attaches its serial line with slcand, brings the slcan interface up,
    adds the two cangw routes, and returns once the board's first heartbeat is on `iface`.
    `boot_s` is how long that took."""

    name: str
    node_id: int
    iface: str
    log_dir: Path
    qemu: LocalQemu | RemoteQemu | None = None
    slcand: subprocess.Popen | None = None
    boot_s: float = 0.0
    routes: list[list[str]] = field(default_factory=list)
    # The line's counts when the board stopped (`link_statistics`).
    statistics: dict[str, int] = field(default_factory=dict)
    # cangw filters of the routes from the bus to the board, one route each (keep them disjoint:
    # a frame that passes two is delivered twice). Default: `acceptance(node_id)`.
    to_board: tuple[str, ...] | None = None
    # The firmware's ELF: default `firmware()`, the production build (e.g.
    # `single_bank_firmware()`, the flash model of the G474 in single-bank mode).
    elf: Path | None = None
    # Whether the board's QEMU runs ahead of the suite's other work (BOARD_NICENESS_STEP): for
    # the tests that time the board itself.
    ahead: bool = False
    # Behind the bootloader: `elf` is then the bootloader's (`BehindBootloader`).
    boot: BehindBootloader | None = None

    @property
    def can_iface(self) -> str:
        return f"pabslcan{self.node_id}"

    @property
    def pid(self) -> int | None:
        return self.qemu.pid if self.qemu else None

    def running(self) -> bool:
        return self.qemu is not None and self.qemu.running()

    def start(self) -> None:
        from . import protocol as p
        import can

        for tool in ("slcand", "cangw", "ip"):
            if shutil.which(tool) is None:
                raise BoardError(f"{tool} is missing (Debian: apt-get install can-utils iproute2)")
        self.log_dir.mkdir(parents=True, exist_ok=True)
        log = self.log_dir / f"{self.name}.log"
        heartbeat = p.frame_id(p.HEARTBEAT, self.node_id, p.BROADCAST)
        listener = can.Bus(interface="socketcan", channel=self.iface, can_filters=[
            {"can_id": heartbeat, "can_mask": 0x1FFFFFFF, "extended": True}])
        try:
            started = time.monotonic()
            self.qemu = qemu_here_or_on_host(self.elf or firmware(), log, self.ahead, self.boot)
            line = self.qemu.start()
            self._bridge(line)
            deadline = started + START_TIMEOUT_S
            while time.monotonic() < deadline:
                if listener.recv(timeout=0.2) is not None:
                    self.boot_s = time.monotonic() - started
                    return
                if not self.running():
                    break
            raise BoardError(f"board {self.name}: no heartbeat from node {self.node_id} on "
                             f"{self.iface} within {START_TIMEOUT_S:.0f} s; its log: {log}")
        except BaseException:
            self.stop()
            raise
        finally:
            listener.shutdown()

    def _bridge(self, line: str) -> None:
        """slcand on `line`, the interface up, cangw both ways."""
        if Path(f"/sys/class/net/{self.can_iface}").exists():
            raise BoardError(f"{self.can_iface} exists already (a board left over?)")
        # -o open the channel, -c close it at exit, -s6 500 kbit/s, -S the line's speed,
        # -F stay in the foreground (this process owns it).
        self.slcand = subprocess.Popen(
            ["slcand", "-o", "-c", f"-s{SLCAN_BITRATE}", "-S", str(BAUD), "-F", line,
             self.can_iface],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 10
        while not Path(f"/sys/class/net/{self.can_iface}").exists():
            if self.slcand.poll() is not None or time.monotonic() > deadline:
                raise BoardError(f"slcand did not make {self.can_iface} on {line} "
                                 f"(is the slcan module loaded?)")
            time.sleep(0.05)
        _run(["ip", "link", "set", self.can_iface, "txqueuelen", str(LINE_QUEUE)])
        _run(["ip", "link", "set", "up", self.can_iface])
        # Frames routed onto a vcan are seen by its sockets only if echoed (-e). can-gw's hop
        # limit (1) keeps each frame from coming back the way it went. The routes to the board
        # are its acceptance filter (`acceptance`).
        to_board = self.to_board if self.to_board is not None else acceptance(self.node_id)
        for route in (*(["-s", self.iface, "-d", self.can_iface, "-f", f] for f in to_board),
                      ["-s", self.can_iface, "-d", self.iface, "-e"]):
            _run(["cangw", "-A", *route])
            self.routes.append(route)

    def reset(self) -> None:
        """The board reboots (QEMU's system_reset); its stored table is kept, the bridge too."""
        if self.qemu is None:
            raise BoardError(f"board {self.name} is not running")
        self.qemu.reset()

    def kill(self) -> None:
        """The board stops at once (QEMU ends): a power cut, and the RAM-backed store is lost.
        QEMU first, the line's bookkeeping (its counts, the routes, slcand) after: in the other
        order the board kept talking through that bookkeeping, whose process spawns take tens of
        milliseconds of the micro-VM's CPU under software emulation, so its last frames reached
        the nodes in the VM exactly while they waited for a CPU (the multi-target test's r2 read
        the killed board's last claim 41 to 44 ms late on a quiet machine, past 50 ms in CI)."""
        if self.qemu is not None:
            self.qemu.stop()
        self.stop()

    def link_statistics(self) -> dict[str, int]:
        """The serial line's frame counts: frames to the board and from it (the kernel's slcan
        interface), and frames lost on the way, by cangw (`refused`: the line's queue was full)
        or by the interface (`dropped`). Empty once the interface is gone."""
        stats = Path(f"/sys/class/net/{self.can_iface}/statistics")
        try:
            counts = {key: int((stats / name).read_text()) for key, name in (
                ("to_board", "tx_packets"), ("to_board_dropped", "tx_dropped"),
                ("from_board", "rx_packets"), ("from_board_dropped", "rx_dropped"))}
        except (OSError, ValueError):
            return {}
        listed = subprocess.run(["cangw", "-L"], stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True).stdout
        counts["to_board_refused"] = counts["from_board_refused"] = 0
        for line in listed.splitlines():
            # "cangw -A -s vcan0 -d pabslcan1 -f ... # 447 handled 0 dropped 298 deleted"
            found = re.search(r"# \d+ handled (\d+) dropped", line)
            if found is None:
                continue
            if f"-d {self.can_iface} " in line + " ":
                counts["to_board_refused"] += int(found.group(1))
            elif f"-s {self.can_iface} " in line:
                counts["from_board_refused"] += int(found.group(1))
        return counts

    def line_losses(self) -> int:
        """Frames the serial line lost either way (`link_statistics`, read when the board
        stopped): a test that judges the board needs 0, or it would judge the emulation."""
        return sum(value for key, value in self.statistics.items()
                   if key.endswith(("_dropped", "_refused")))

    def stop(self) -> None:
        if self.routes:
            # What the line carried and lost, kept and written to the node's log directory.
            self.statistics = self.link_statistics()
            (self.log_dir / f"{self.name}-link.txt").write_text(
                "".join(f"{key} {value}\n" for key, value in self.statistics.items()))
        while self.routes:
            route = self.routes.pop()
            subprocess.run(["cangw", "-D", *route], stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
        if self.slcand is not None:
            if self.slcand.poll() is None:
                self.slcand.send_signal(signal.SIGTERM)
                try:
                    self.slcand.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    self.slcand.kill()
                    self.slcand.wait(timeout=5)
            self.slcand = None
        if self.qemu is not None:
            self.qemu.stop()
            self.qemu = None


class HostBoards:
    """The micro-VM's host side of `RemoteQemu`: serves the guest's requests on the control
    socket, running the board's QEMU here with UART0 on the UART socket.

    The micro-VM's QEMU is the server of both unix sockets (`serials`, its ttyS1 and ttyS2); the
    board's QEMU connects to the first when started, this service to the second."""

    def __init__(self) -> None:
        self.dir = Path(tempfile.mkdtemp(prefix="pab-hil-board-"))
        self.uart = self.dir / "uart.sock"
        self.control = self.dir / "control.sock"
        self.monitor = self.dir / "monitor.sock"
        self.qemu: subprocess.Popen | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def serials(self) -> list[Path]:
        """The micro-VM's serial ports after its console, in order: ttyS1, ttyS2."""
        return [self.uart, self.control]

    def start(self) -> None:
        self._thread = threading.Thread(target=self._serve, name="board-host", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._stop_qemu()
        shutil.rmtree(self.dir, ignore_errors=True)

    def _serve(self) -> None:
        """Connects to the control socket and answers requests; connects again whenever the
        micro-VM's QEMU goes (a KVM attempt that fell back to TCG starts a second one)."""
        while not self._stop.is_set():
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                sock.connect(str(self.control))
            except OSError:
                sock.close()
                time.sleep(0.1)
                continue
            with sock:
                self._answer(sock)

    def _answer(self, sock: socket.socket) -> None:
        sock.settimeout(0.2)
        pending = b""
        while not self._stop.is_set():
            try:
                chunk = sock.recv(4096)
            except socket.timeout:
                continue
            except OSError:
                return
            if not chunk:
                return
            pending += chunk
            while b"\n" in pending:
                line, pending = pending.split(b"\n", 1)
                answer = self._handle(line.decode(errors="replace").strip())
                try:
                    sock.sendall(answer.encode() + b"\n")
                except OSError:
                    return

    def _handle(self, request: str) -> str:
        words = request.split()
        try:
            options = words[3:]
            ahead = options[:1] == ["ahead"]
            options = options[1:] if ahead else options
            boot = (BehindBootloader(Path(options[1]), Path(options[2]))
                    if len(options) == 3 and options[0] == "boot" else None)
            if words[:1] == ["start"] and len(words) >= 3 and (not options or boot):
                self._stop_qemu()
                with open(words[2], "ab") as log:
                    self.qemu = subprocess.Popen(
                        qemu_command(Path(words[1]), f"unix:{self.uart}", self.monitor, boot),
                        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=log,
                        preexec_fn=_board_first if ahead else None)
                return f"ok {self.qemu.pid}"
            if words == ["reset"]:
                if self.qemu is None or self.qemu.poll() is not None:
                    return "error the board is not running"
                monitor_command(self.monitor, "system_reset")
                return "ok"
            if words == ["stop"]:
                self._stop_qemu()
                return "ok"
            return f"error unknown request {request!r}"
        except (OSError, BoardError) as error:
            return f"error {error}"

    def _stop_qemu(self) -> None:
        if self.qemu is not None and self.qemu.poll() is None:
            self.qemu.terminate()
            try:
                self.qemu.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.qemu.kill()
                self.qemu.wait(timeout=5)
        self.qemu = None
