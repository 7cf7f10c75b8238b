"""Booting the micro-VM, and which accelerator: KVM when it works, software emulation otherwise.

`PAB_HIL_ACCEL` chooses: `tcg` (software emulation only), `kvm` (KVM only: any failure is an
error), or `auto` (the default): KVM if /dev/kvm is usable, and TCG if KVM fails *before the guest
shows its first sign of life* (the init script's first line). KVM fails in many ways on hosts that
expose /dev/kvm: QEMU exits at once, aborts on an assertion (an MSR the host refuses), prints an
error and stops, or hangs silently (nested KVM). All of them fall back, with one line saying which.
After the guest has shown life, a failure is the job's failure, never a reason to start over: the
job may have run half-way and its results would be overwritten.
"""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

ACCEL_ENV = "PAB_HIL_ACCEL"
ACCEL_MODES = ("auto", "kvm", "tcg")
KVM = "KVM"
TCG = "TCG (software emulation)"
QEMU = "qemu-system-x86_64"

KVM_PROBE_S = 6.0  # a KVM guest prints its first line in about 1 s; a hung one never does
BOOT_TIMEOUT_S = 120.0  # QEMU launched -> the job starts, under TCG
LIFE_MARKER = "pab-vm: init"
JOB_MARKER = "pab-vm: job starting"
FIRST_TEST_MARKER = "pab-hil: first test starting"  # printed by hil-sim/tests/conftest.py


class VmError(RuntimeError):
    pass


def say(line: str) -> None:
    print(f"run-hil: {line}", flush=True)


@dataclass
class Outcome:
    status: int  # the job's exit status
    accel: str  # KVM or TCG
    boot_s: float  # QEMU launched -> job starting, on the host's clock
    total_s: float = 0.0


@dataclass
class NoLife:
    """QEMU failed before the guest's first sign of life: why, in a few words."""
    reason: str


def accel_mode(environ: dict[str, str] | None = None) -> str:
    """The accelerator policy from PAB_HIL_ACCEL (default auto); VmError for anything else."""
    value = (os.environ if environ is None else environ).get(ACCEL_ENV, "auto").strip().lower()
    if value == "":
        value = "auto"
    if value not in ACCEL_MODES:
        raise VmError(f"{ACCEL_ENV}={value!r}: expected one of {', '.join(ACCEL_MODES)} "
                      "(auto: KVM if it boots, else software emulation)")
    return value


def kvm_usable() -> bool:
    return os.access("/dev/kvm", os.R_OK | os.W_OK)


def boot(kernel: Path, initrd: Path, out_dir: Path, timeout_s: float, mode: str,
         kvm_available: bool | None = None, probe_s: float = KVM_PROBE_S,
         boot_timeout_s: float = BOOT_TIMEOUT_S, serials: Sequence[Path] = ()) -> Outcome:
    """Boots the micro-VM under the accelerator `mode` allows; returns once QEMU has stopped.

    `serials` are unix sockets (QEMU listens on them) that the guest sees as its serial ports
    after the console: ttyS1, ttyS2, ... The guest writes the job's exit status into
    `out_dir`/job.status; without it, VmError."""
    if kvm_available is None:
        kvm_available = kvm_usable()
    status_file = out_dir / "job.status"
    status_file.unlink(missing_ok=True)

    def attempt(accel: str, probe: float | None) -> Outcome | NoLife:
        return _run_qemu(_command(kernel, initrd, out_dir, accel, serials), accel, out_dir,
                         timeout_s, probe, boot_timeout_s)

    if mode == "tcg":
        say("software emulation (TCG), as PAB_HIL_ACCEL=tcg asks")
        result = attempt(TCG, None)
    elif mode == "kvm":
        if not kvm_available:
            raise VmError("PAB_HIL_ACCEL=kvm, but /dev/kvm is missing or not usable here")
        say("booting with KVM, as PAB_HIL_ACCEL=kvm asks (no fallback)")
        result = attempt(KVM, probe_s)
        if isinstance(result, NoLife):
            raise VmError(f"KVM failed before the guest started: {result.reason}")
    elif kvm_available:
        say("booting with KVM")
        result = attempt(KVM, probe_s)
        if isinstance(result, NoLife):
            say(f"KVM failed before the guest started ({result.reason}): "
                "falling back to software emulation (TCG)")
            status_file.unlink(missing_ok=True)
            result = attempt(TCG, None)
    else:
        say("/dev/kvm is not usable here: software emulation (TCG)")
        result = attempt(TCG, None)
    if isinstance(result, NoLife):
        raise VmError(f"the micro-VM did not start under {TCG}: {result.reason}")
    if not status_file.exists():
        raise VmError("the micro-VM stopped without the job's exit status (see its console above)")
    text = status_file.read_text().strip()
    result.status = int(text) if text.lstrip("-").isdigit() else 1
    return result


def _command(kernel: Path, initrd: Path, out_dir: Path, accel: str,
             serials: Sequence[Path] = ()) -> list[str]:
    accel_args = ["-enable-kvm", "-cpu", "host"] if accel == KVM else ["-accel", "tcg", "-cpu", "max"]
    cpus = max(1, min(4, os.cpu_count() or 1))
    return [
        QEMU, *accel_args, "-m", "2048", "-smp", str(cpus),
        "-nodefaults", "-no-user-config",  # no VGA, no NIC and its option ROM
        "-kernel", str(kernel), "-initrd", str(initrd),
        # mitigations=off: nothing to protect in a throwaway guest, and KPTI & co. cost a lot
        # under emulation.
        "-append", f"console=ttyS0 quiet panic=-1 mitigations=off pab_out={out_dir}",
        "-display", "none", "-no-reboot", "-serial", "stdio", "-monitor", "none",
        "-virtfs", "local,path=/,mount_tag=host,security_model=none,readonly=on,multidevs=remap",
        "-virtfs", f"local,path={out_dir},mount_tag=out,security_model=none",
        *(argument for number, path in enumerate(serials, start=1) for argument in (
            "-chardev", f"socket,id=serial{number},path={path},server=on,wait=off",
            "-serial", f"chardev:serial{number}")),
    ]


def _is_qemu_error(text: str) -> bool:
    """A line QEMU itself printed that is not a warning (`qemu-system-x86_64: ...`)."""
    prefix = f"{QEMU}:"
    return text.startswith(prefix) and not text[len(prefix):].lstrip().startswith("warning")


def _exit_reason(returncode: int) -> str:
    if returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = f"signal {-returncode}"
        return f"QEMU was killed by {name}"
    return f"QEMU exited with status {returncode}"


def _run_qemu(command: list[str], accel: str, out_dir: Path, timeout_s: float,
              probe_s: float | None, boot_timeout_s: float) -> Outcome | NoLife:
    """Runs QEMU, copying its console to stdout. With `probe_s`, any failure before the guest's
    first line is a NoLife (and QEMU is stopped); without, it is a VmError."""
    launched = time.monotonic()
    try:
        qemu = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT)
    except OSError as error:
        raise VmError(f"cannot start {command[0]}: {error}") from error
    lines: queue.Queue[bytes | None] = queue.Queue()

    def pump() -> None:
        assert qemu.stdout is not None
        for line in qemu.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()

    def stop() -> None:
        if qemu.poll() is None:
            qemu.kill()
        qemu.wait()

    alive = False
    boot_s = first_test_s = 0.0
    deadline = launched + (probe_s if probe_s is not None else boot_timeout_s)
    while True:
        try:
            line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            stop()
            if not alive:
                waited = probe_s if probe_s is not None else boot_timeout_s
                reason = f"no sign of life from the guest within {waited:.0f} s"
                if probe_s is not None:
                    return NoLife(reason)
                raise VmError(f"the micro-VM ({accel}) did not boot: {reason}; stopped it")
            what = "finish the job" if boot_s else "start the job"
            raise VmError(f"the micro-VM ({accel}) did not {what} in time; stopped it")
        if line is None:
            break
        text = line.decode(errors="replace")
        sys.stdout.write(text)
        sys.stdout.flush()
        if not alive and _is_qemu_error(text):
            stop()
            reason = f"QEMU reported an error: {text.strip()[len(QEMU) + 1:].strip()}"
            if probe_s is not None:
                return NoLife(reason)
            raise VmError(f"the micro-VM ({accel}) did not start: {reason}")
        if text.startswith(LIFE_MARKER) and not alive:
            alive = True
            deadline = launched + boot_timeout_s
        elif text.startswith(JOB_MARKER) and not boot_s:
            boot_s = time.monotonic() - launched
            say(f"micro-VM booted in {boot_s:.1f} s ({accel}); the job runs")
            deadline = launched + timeout_s
        elif FIRST_TEST_MARKER in text and boot_s and not first_test_s:
            first_test_s = time.monotonic() - launched
            (out_dir / "vm-boot.txt").write_text(
                f"boot {boot_s:.1f} s, first test {first_test_s:.1f} s after QEMU started ({accel})\n")
    returncode = qemu.wait()
    if not alive:
        reason = _exit_reason(returncode) + " before the guest started"
        if probe_s is not None:
            return NoLife(reason)
        raise VmError(f"the micro-VM ({accel}) did not start: {reason}")
    return Outcome(status=-1, accel=accel, boot_s=boot_s)
