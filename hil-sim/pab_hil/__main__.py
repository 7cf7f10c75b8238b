"""pab-hil: hardware-in-the-loop for pab nodes on a SocketCAN bus.

  python -m pab_hil run take-and-return --iface vcan0 --plot out.png
  python -m pab_hil suite            (what hil-sim/run-hil runs)
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

from .nodes import NODE_IDS, REPO, TAKE_AND_RETURN, MissingBinary

SCENARIOS = {
    "take-and-return": "A to F: the robot takes the object the person shows and hands it back",
    "take-back": "the person takes the object back while the arm approaches: back to A",
}
DEFAULT_OUT = Path(os.environ.get("CARGO_TARGET_DIR", REPO / "target")) / "hil"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m pab_hil",
        description="Hardware-in-the-loop for pab nodes: pab-node processes on a SocketCAN bus, "
        "the Take and Return world and its seven behaviours in python-can, closed loop.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    commands = parser.add_subparsers(dest="command", required=True)

    run = commands.add_parser(
        "run",
        help="run one scenario on a bus and save its candump log and stimulation plot",
        description="Starts Arm, Hand and Gaze Control as pab-node processes on IFACE, pushes "
        "their tables with `pabctl push`, forks the seven behaviours of Figure 4, and lets the "
        "world run until the scenario ends. Writes OUT/bus.log (candump -L format: replay it "
        "with `canplayer -I`), OUT/phases.txt, the nodes' logs, and the plot.\n\nScenarios:\n"
        + "\n".join(f"  {name:18} {text}" for name, text in SCENARIOS.items()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    run.add_argument("scenario", choices=SCENARIOS)
    run.add_argument("--iface", default="vcan0", help="SocketCAN interface (default: vcan0)")
    run.add_argument("--network", type=Path, default=TAKE_AND_RETURN,
                     help="network file to push (default: examples/take-and-return.toml)")
    run.add_argument("--out", type=Path, default=None,
                     help="directory for the log and the nodes' stores (default: target/hil/<scenario>)")
    run.add_argument("--plot", type=Path, default=None,
                     help="draw the stimulation levels from the nodes' diagnostic stream here (PNG)")
    run.add_argument("--timeout", type=float, default=90.0,
                     help="give up after this many seconds (default: 90)")
    run.add_argument("--board", action="append", choices=sorted(NODE_IDS), default=[],
                     metavar="NODE",
                     help="run this node as the emulated Cortex-M4 board (pab-fw-an386 in "
                     "qemu-system-arm, bridged with slcand and cangw) instead of pab-node; "
                     "repeatable on a workstation (the micro-VM has one). Needs root, can-utils, "
                     "qemu-system-arm, the slcan and can-gw modules")

    suite = commands.add_parser(
        "suite",
        help="run the HIL pytest suite on vcan0, or in a micro-VM where the kernel has no vcan",
        description="Picks where the suite runs and says which: an existing vcan0 and vcan1 "
        "(MTU 72: the CAN FD tests' bus); ones it creates (root, kernel with vcan); else a QEMU "
        "micro-VM with the distribution's kernel, which has both. "
        "Extra arguments go to pytest. Exits with pytest's status.",
        epilog="environment:\n"
        "  PAB_HIL_ACCEL=auto|kvm|tcg  the micro-VM's accelerator (default auto: KVM if /dev/kvm\n"
        "                              is usable and the guest starts under it, else software\n"
        "                              emulation, TCG; any KVM failure before the guest's first\n"
        "                              line falls back, with one line saying why). kvm: KVM or\n"
        "                              fail. tcg: never try KVM.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    suite.add_argument("--out", type=Path, default=DEFAULT_OUT,
                       help=f"results directory (default: {DEFAULT_OUT})")
    suite.add_argument("--way", choices=["auto", "host", "vm"], default="auto",
                       help="force the host's vcan0 and vcan1 or the micro-VM (default: auto)")
    # A guard against a hung job, not a budget: the suite takes about 6 minutes on a quiet 2-core
    # machine under software emulation and about 9 beside two busy processes.
    suite.add_argument("--timeout", type=float, default=1800.0,
                       help="stop the micro-VM after this many seconds (default: 1800)")
    suite.add_argument("--hogs", type=int, default=os.environ.get("PAB_HIL_HOGS", "0"),
                       metavar="N",
                       help="run N busy processes at normal priority beside the suite, one per "
                       "core for a machine half as fast (default: PAB_HIL_HOGS, else 0): the "
                       "suite must pass on slower machines than yours")
    suite.add_argument("--command", default=None, metavar="CMD",
                       help="run this shell command instead of pytest, where the suite would run "
                       "(e.g. --command 'python -m pab_hil run take-and-return --plot "
                       "target/hil/take-and-return.png' on a machine without vcan)")
    suite.add_argument("pytest_args", nargs=argparse.REMAINDER,
                       help="passed to pytest (after --)")

    margins = commands.add_parser(
        "margins",
        help="the smallest margin of each timing bound over several runs' results",
        description="Reads the timing bounds each run wrote (RESULTS/bounds.jsonl, where "
        "run-hil --out put them) and prints, per bound, its smallest margin and the run it "
        "came from.",
    )
    margins.add_argument("results", type=Path, nargs="+", metavar="RESULTS",
                         help="a run's results directory (run-hil's --out)")

    args = parser.parse_args(argv)
    try:
        if args.command == "margins":
            from . import bounds

            lines = bounds.smallest(args.results)
            print("\n".join(lines) if lines else "no timing bounds in " +
                  ", ".join(str(r) for r in args.results))
            return 0 if lines else 1
        if args.command == "run":
            return run_scenario(args)
        return run_suite(args)
    except MissingBinary as error:
        print(f"pab-hil: {error}", file=sys.stderr)
        return 2
    except RuntimeError as error:  # vm.VmError among them: what failed, not a traceback
        print(f"run-hil: error: {error}", file=sys.stderr)
        return 2


def run_scenario(args) -> int:
    from .person import TakeAndReturn
    from .plot import plot_session
    from .scenario import ScenarioError, Session

    out = args.out or DEFAULT_OUT / args.scenario
    if out.exists():
        shutil.rmtree(out)  # a run starts with empty node stores
    person = TakeAndReturn(takes_back=args.scenario == "take-back")
    print(f"pab-hil: {args.scenario} on {args.iface}; results in {out}")
    started = time.monotonic()
    status = 0
    session = Session(args.iface, out, network=args.network, person=person,
                      progress=lambda line: print(f"  {line}", flush=True),
                      boards=tuple(args.board))
    try:
        with session:
            done = _back_to_rest(session)
            last = ""
            deadline = time.monotonic() + args.timeout
            while not done():
                if time.monotonic() > deadline:
                    raise ScenarioError(f"{args.scenario} did not end within {args.timeout:.0f} s")
                phases = " ".join(session.phases.sequence())
                if phases != last:
                    print(f"  {session.world.now():6.1f} s  phases {phases}", flush=True)
                    last = phases
                time.sleep(0.1)
    except ScenarioError as error:
        print(f"pab-hil: {error}", file=sys.stderr)
        status = 1
    print(session.phase_report())
    print(f"pab-hil: candump log {session.log_path} ({time.monotonic() - started:.1f} s)")
    if args.plot:
        plot_session(session, args.plot, title=f"{args.scenario} on {args.iface}")
        print(f"pab-hil: stimulation plot {args.plot}")
    return status


def _back_to_rest(session):
    """Both scenarios end the same way: the person has the object and has left, phase A again."""
    from . import world as w

    def back_to_rest() -> bool:
        s = session.world.snapshot()
        return (
            session.phases.sequence()[-1:] == ["A"]
            and len(session.phases.sequence()) > 1
            and s.holder == w.PERSON_KEEPS
            and not s.face_present
        )

    return back_to_rest


# -- the suite -------------------------------------------------------------------------------


def run_suite(args) -> int:
    from . import vm

    vm.accel_mode()  # a mistyped PAB_HIL_ACCEL fails now, not after the build of the guest
    out: Path = args.out.resolve()
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    extra = [a for a in args.pytest_args if a != "--"]
    way = args.way
    if way == "auto":
        way = "host" if _host_vcan("vcan0") and _host_vcan(FD_IFACE, CANFD_MTU) else "vm"
    elif way == "host" and not (_host_vcan("vcan0") and _host_vcan(FD_IFACE, CANFD_MTU)):
        print(f"run-hil: no vcan0 and {FD_IFACE} (MTU {CANFD_MTU}) on this machine and none can "
              "be made", file=sys.stderr)
        return 2
    # --durations=0: every test's time in the log, to watch the suite's growth against CI's budget.
    pytest = [sys.executable, "-m", "pytest", str(REPO / "hil-sim" / "tests"),
              "--iface", "vcan0", "--fd-iface", FD_IFACE, "--hil-out", str(out), "-ra",
              "--durations=0",
              "--durations-min=1", *extra]
    if args.command:
        # The venv's python first on PATH, so `python -m pab_hil ...` works as typed.
        command = f"PATH={shlex.quote(str(Path(sys.executable).parent))}:$PATH; {args.command}"
    else:
        command = " ".join(shlex.quote(a) for a in pytest)
    if args.hogs < 0:
        print(f"run-hil: --hogs {args.hogs}: a number of processes, 0 or more", file=sys.stderr)
        return 2
    hogs = Hogs(args.hogs)
    # After the hogs started: they keep the priority any other user's work would have.
    priority = _emulators_first()
    started = time.monotonic()
    try:
        status, way_text = _run_where(args, way, command, out)
    finally:
        hogs.stop()
    elapsed = time.monotonic() - started
    _print_figures(out)
    what = f"`{args.command}`" if args.command else "HIL suite"
    verdict = "passed" if status == 0 else f"FAILED (status {status})"
    slowed = f", beside {args.hogs} busy processes" if args.hogs else ""
    way_text += priority
    print(f"run-hil: {what} {verdict} in {elapsed:.0f} s ({way_text}{slowed}); results in {out}")
    return status


#: The niceness the suite's emulators (the micro-VM's QEMU, the boards' QEMUs) and the nodes run at
#: when this process may raise its priority (root or CAP_SYS_NICE). Under software emulation a
#: guest vCPU the host puts aside for a few time slices stops every process on it: beside two busy
#: processes at normal priority, a behaviour and a node of the guest once published nothing for
#: 1.6 s while the rest of the bus went on, and the estop of a node in the guest took 43 ms where a
#: quiet machine takes under 10. A real HIL rig runs its emulators ahead of other work in the same
#: way; it does not make a slower CPU faster (the factors of `speed` follow that).
EMULATOR_NICENESS = -10


def _emulators_first() -> str:
    """Raises this process's priority, which its children (QEMUs, nodes, the suite) inherit, to
    EMULATOR_NICENESS; the text run-hil's last line says about it."""
    from . import vm

    current = os.getpriority(os.PRIO_PROCESS, 0)
    if current <= EMULATOR_NICENESS:
        return f", niceness {current}"
    try:
        os.setpriority(os.PRIO_PROCESS, 0, EMULATOR_NICENESS)
    except PermissionError:
        vm.say(f"could not raise the emulators' priority to niceness {EMULATOR_NICENESS} (not root, "
               "no CAP_SYS_NICE): other work on this machine can delay the nodes past the suite's "
               "bounds")
        return f", niceness {current} (could not raise it)"
    vm.say(f"the emulators and nodes run at niceness {EMULATOR_NICENESS}, ahead of other work")
    return f", niceness {EMULATOR_NICENESS}"


class Hogs:
    """`count` processes that spin at normal priority until stopped: a slower machine on purpose.
    Each takes a core's share from the suite (and the micro-VM's QEMU) as another user's work
    would."""

    def __init__(self, count: int) -> None:
        self.processes = [
            subprocess.Popen([sys.executable, "-c", "while True: pass"],
                             stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
            for _ in range(count)
        ]
        if count:
            from . import vm
            vm.say(f"{count} busy processes run beside the suite (--hogs)")

    def stop(self) -> None:
        for process in self.processes:
            process.kill()
            process.wait()


def _run_where(args, way: str, command: str, out: Path) -> tuple[int, str]:
    """Runs `command` on this machine's vcan0 or in the micro-VM: (status, where)."""
    from . import board, vm

    if way == "host":
        vm.say("using this machine's vcan0")
        status = subprocess.run(["/bin/sh", "-c", command], cwd=REPO).returncode
        way_text = "this machine's vcan0"
    else:
        vm.say("no vcan0 on this machine (kernel without SocketCAN): running the suite in a micro-VM")
        # The guest mounts its scratch space over /run (see vm/init): what lives there on the
        # host would be hidden from the job.
        for what, path in (("the sources", REPO), ("the results directory", out),
                           ("the Python venv", Path(sys.prefix))):
            if path.resolve().is_relative_to("/run"):
                print(f"run-hil: error: {what} ({path}) lies under /run, which the micro-VM "
                      "covers with its scratch space: use a directory elsewhere", file=sys.stderr)
                return 2, "not run"
        # Bytecode for the harness now: the guest sees the sources read-only and would compile
        # them at every import, under emulation.
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(REPO / "hil-sim")], check=True)
        mpl = out / ".matplotlib"
        # Build matplotlib's font cache here: in the guest it would take a minute of emulation.
        subprocess.run([sys.executable, "-c", "import matplotlib.pyplot"],
                       env=dict(os.environ, MPLCONFIGDIR=str(mpl)), check=True)
        job = "\n".join([
            "# Written by pab_hil suite; run by the micro-VM's /init, chrooted into the host's root.",
            f"export PATH={shlex.quote(os.environ.get('PATH', '/usr/bin:/bin'))}",
            "export HOME=/run/home TMPDIR=/run/tmp PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1",
            f"export MPLCONFIGDIR={shlex.quote(str(mpl))}",
            *(f"export {name}={shlex.quote(os.environ[name])}"
              for name in ("PAB_BIN_DIR", "CARGO_TARGET_DIR", "PAB_BOARD_ELF") if name in os.environ),
            "export PAB_HIL_WAY='micro-VM'",
            # The emulated board's QEMU runs here, on the host (see pab_hil.board): its UART0
            # is the guest's ttyS1, and the guest asks for it on ttyS2.
            f"export {board.UART_ENV}=/dev/ttyS1 {board.CONTROL_ENV}=/dev/ttyS2",
            f"cd {shlex.quote(str(REPO))}",
            "ip link show vcan0 | head -1",
            f"ip link show {FD_IFACE} | head -1",
            command + (" --color=no" if not args.command else ""),
            "",
        ])
        boards = board.HostBoards()
        boards.start()
        try:
            outcome = vm.run(job, out, out / ".." / "hil-vm", timeout_s=args.timeout,
                             serials=boards.serials)
        finally:
            boards.close()
        status = outcome.status
        way_text = f"micro-VM, {outcome.accel}, booted in {outcome.boot_s:.1f} s"
    return status, way_text


#: The CAN FD tests' bus (MTU 72), beside the classic vcan0: `--fd-iface` of the suite.
FD_IFACE = "vcan1"
CANFD_MTU = 72


def _host_vcan(name: str, mtu: int | None = None) -> bool:
    """Whether `name` exists (with MTU `mtu`, if given), creating it (root, kernel with vcan) if
    it can."""
    path = Path(f"/sys/class/net/{name}")
    if path.exists():
        if mtu is None or int((path / "mtu").read_text()) == mtu:
            return True
        if os.geteuid() != 0:
            return False
        subprocess.run(["ip", "link", "set", "down", name], check=True)
        subprocess.run(["ip", "link", "set", name, "mtu", str(mtu)], check=True)
        subprocess.run(["ip", "link", "set", "up", name], check=True)
        print(f"run-hil: set {name}'s MTU to {mtu}")
        return True
    if os.geteuid() != 0 or shutil.which("ip") is None:
        return False
    if shutil.which("modprobe"):
        # can-isotp too: the tests' independent ISO-TP sender is the kernel's (pab_hil.transfer).
        for module in ("vcan", "can-isotp"):
            subprocess.run(["modprobe", module], stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    added = subprocess.run(["ip", "link", "add", "dev", name, "type", "vcan"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if added.returncode != 0:
        return False
    if mtu is not None:
        subprocess.run(["ip", "link", "set", name, "mtu", str(mtu)], check=True)
    subprocess.run(["ip", "link", "set", "up", name], check=True)
    print(f"run-hil: created {name}" + (f" (MTU {mtu})" if mtu is not None else ""))
    return True


def _print_figures(out: Path) -> None:
    from . import bounds

    figures = sorted((out / "figures").glob("*.json")) if (out / "figures").exists() else []
    for path in figures:
        data = json.loads(path.read_text())
        print(f"run-hil: figure {path.stem}: " + ", ".join(f"{k} {v}" for k, v in data.items()))
    for line in bounds.report(bounds.read(out)):
        print(line)
    boot = out / "vm-boot.txt"
    if boot.exists():
        print(f"run-hil: figure micro-VM boot to first test: {boot.read_text().strip()}")


if __name__ == "__main__":
    sys.exit(main())
