"""A throwaway micro-VM that has a `vcan0`, for machines whose kernel has no SocketCAN.

The guest is the distribution's own kernel (`kernel`: unpacked from its package, never installed
on the host) booted by QEMU with an initramfs built here (`initramfs`: a static busybox, the
modules). Its `/init` (the file beside this one) loads the modules, creates `vcan0`, mounts the
host's root read-only and the results directory read-write, at their host paths, and runs
`job.sh` from the results directory, chrooted into the host's files: the same venv, binaries and
sources as the host, so the suite runs unchanged. Then it powers off; the job's exit status comes
back in `job.status`. Which accelerator (KVM or software emulation) is `boot`'s decision.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Sequence
from pathlib import Path

from . import debian, initramfs, kernel
from .boot import ACCEL_ENV, ACCEL_MODES, Outcome, VmError, accel_mode, boot, kvm_usable, say
from .kernel import Kernel, KernelError

__all__ = ["ACCEL_ENV", "ACCEL_MODES", "Kernel", "Outcome", "VmError", "accel_mode", "kvm_usable",
           "run", "say"]

# Host commands the micro-VM path needs, and the Debian packages that provide them. cangen,
# slcand and cangw run in the guest, from the host's files (the flood test's frame generator, the
# emulated board's bridge); the emulated board's QEMU runs on the host (pab_hil.board).
HOST_PACKAGES = {
    "qemu-system-x86_64": "qemu-system-x86",
    "qemu-system-arm": "qemu-system-arm",
    "cangen": "can-utils",
}


def ensure_host_tools() -> None:
    """Installs QEMU and can-utils with apt-get if they are missing (root)."""
    missing = [pkg for tool, pkg in HOST_PACKAGES.items() if shutil.which(tool) is None]
    if not missing:
        return
    if os.geteuid() != 0 or shutil.which("apt-get") is None:
        raise VmError(
            f"the micro-VM needs {', '.join(missing)}: install them "
            f"(Debian/Ubuntu: sudo apt-get install {' '.join(missing)})"
        )
    say(f"installing {', '.join(missing)} with apt-get")
    try:
        debian.update_once()
        debian.apt(["apt-get", "install", "-y", "-qq", "--no-install-recommends", *missing])
    except debian.AptError as error:
        raise VmError(str(error)) from error


def run(job: str, out_dir: Path, cache: Path, timeout_s: float,
        serials: Sequence[Path] = ()) -> Outcome:
    """Boots the micro-VM, runs the shell script `job` in it, and returns its exit status.

    The accelerator follows PAB_HIL_ACCEL (see `boot`). The guest's console (the job's output) is
    copied to stdout as it comes. `serials`: unix sockets the guest sees as ttyS1, ttyS2, ...
    """
    mode = accel_mode()
    ensure_host_tools()
    try:
        guest = kernel.prepare(cache)
        busybox = initramfs.static_busybox(cache)
        image = initramfs.build(guest, busybox, cache / "initramfs.cpio.gz")
    except (KernelError, debian.AptError, initramfs.InitramfsError) as error:
        raise VmError(str(error)) from error
    out_dir = out_dir.resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "job.sh").write_text(job)
    say(f"micro-VM: kernel {guest.version}, {len(guest.modules)} modules")
    started = time.monotonic()
    outcome = boot(guest.boot_image, image, out_dir, timeout_s, mode, serials=serials)
    outcome.total_s = time.monotonic() - started
    return outcome
