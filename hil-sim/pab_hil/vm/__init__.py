"""A throwaway micro-VM that has a `vcan0`, for machines whose kernel has no SocketCAN.

The guest is Debian's own kernel (`linux-image-amd64`, unpacked from the .deb, never installed on
the host) booted by QEMU with a busybox initramfs built here. Its `/init` (the file beside this
one) loads the CAN and 9p modules, creates `vcan0`, mounts the host's root read-only and the
results directory read-write, at their host paths, and runs `job.sh` from the results directory,
chrooted into the host's files: the same venv, binaries and sources as the host, so the suite runs
unchanged. Then it powers off; the job's exit status comes back in `job.status`.

KVM is used when it boots; when it does not (no /dev/kvm, or a host whose nested KVM hangs, as
this project's CI machine does) QEMU falls back to software emulation (TCG).
"""

from __future__ import annotations

import gzip
import os
import queue
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

INIT = Path(__file__).with_name("init")

# Load order matters (insmod resolves nothing); the init script loads them in this order too.
MODULES = (
    "virtio_ring", "virtio", "virtio_pci_legacy_dev", "virtio_pci_modern_dev", "virtio_pci",
    "netfs", "fscache", "9pnet", "9pnet_virtio", "9p", "can", "can-raw", "can-dev", "vcan",
)
DEBIAN_PACKAGES = {
    "qemu-system-x86_64": "qemu-system-x86",
    "busybox": "busybox-static",
    "cangen": "can-utils",  # the flood test's frame generator
}
BUSYBOX = Path("/bin/busybox")

# The marker lines of the init script, and how long to wait for them.
KVM_PROBE_S = 6.0  # a KVM guest prints its first line in about 1 s; a hung one never does
BOOT_TIMEOUT_S = 120.0
FIRST_TEST_MARKER = "pab-hil: first test starting"  # printed by hil-sim/tests/conftest.py


class VmError(RuntimeError):
    pass


@dataclass
class Kernel:
    version: str
    vmlinuz: Path
    modules: Path  # the directory holding <name>.ko for every name in MODULES

    @property
    def boot_image(self) -> Path:
        """The uncompressed ELF kernel if it could be extracted, else the bzImage.

        QEMU boots an ELF vmlinux straight into 64-bit code (PVH, CONFIG_PVH=y in Debian's
        kernel): no real-mode setup and no decompression, which under emulation saves about 6 s
        of the boot."""
        vmlinux = self.vmlinuz.with_name("vmlinux")
        if not vmlinux.exists():
            extracted = _extract_vmlinux(self.vmlinuz.read_bytes())
            if extracted is None:
                return self.vmlinuz
            vmlinux.write_bytes(extracted)
        return vmlinux


def _extract_vmlinux(bzimage: bytes) -> bytes | None:
    """The ELF image inside a bzImage compressed with xz or gzip (what the stdlib can undo)."""
    import lzma
    import zlib

    for magic, decompressor in ((b"\xfd7zXZ\x00", lambda: lzma.LZMADecompressor(lzma.FORMAT_XZ)),
                                (b"\x1f\x8b\x08", lambda: zlib.decompressobj(16 + zlib.MAX_WBITS))):
        start = bzimage.find(magic)
        while start >= 0:
            try:
                image = decompressor().decompress(bzimage[start:])
            except (lzma.LZMAError, zlib.error):
                image = b""
            if image.startswith(b"\x7fELF"):
                return image
            start = bzimage.find(magic, start + 1)
    return None


@dataclass
class Outcome:
    status: int  # the job's exit status
    accel: str  # "KVM" or "TCG (software emulation)"
    boot_s: float  # QEMU launched -> job starting, on the host's clock
    total_s: float


def say(line: str) -> None:
    print(f"run-hil: {line}", flush=True)


# -- host prerequisites ----------------------------------------------------------------------


def ensure_host_tools() -> None:
    """Installs QEMU, busybox-static and can-utils with apt-get if they are missing (root)."""
    missing = [pkg for tool, pkg in DEBIAN_PACKAGES.items() if shutil.which(tool) is None]
    if BUSYBOX.exists() and "busybox-static" in missing:
        missing.remove("busybox-static")
    if not missing:
        return
    if os.geteuid() != 0 or shutil.which("apt-get") is None:
        raise VmError(
            f"the micro-VM needs {', '.join(missing)}: install them "
            f"(Debian/Ubuntu: sudo apt-get install {' '.join(missing)})"
        )
    say(f"installing {', '.join(missing)} with apt-get")
    _apt(["apt-get", "update", "-qq"])
    _apt(["apt-get", "install", "-y", "-qq", "--no-install-recommends", *missing])


def _apt(command: list[str], cwd: Path | None = None) -> None:
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    result = subprocess.run(command, cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    if result.returncode != 0:
        raise VmError(f"`{' '.join(command)}` failed:\n{result.stdout[-3000:]}")


def kernel(cache: Path) -> Kernel:
    """Debian's current kernel package, downloaded and unpacked into `cache` once."""
    cache.mkdir(parents=True, exist_ok=True)
    for unpacked in sorted(cache.glob("linux-*/boot/vmlinuz-*")):
        root = unpacked.parents[1]
        version = unpacked.name.removeprefix("vmlinuz-")
        return Kernel(version, unpacked, _modules_dir(root, version))
    package = _kernel_package()
    say(f"downloading {package} (Debian's kernel, for the micro-VM; once)")
    download = cache / "download"
    download.mkdir(exist_ok=True)
    try:
        _apt(["apt-get", "download", package], cwd=download)
    except VmError:
        _apt(["apt-get", "update", "-qq"])
        _apt(["apt-get", "download", package], cwd=download)
    (deb,) = download.glob(f"{package}_*.deb")
    root = cache / f"linux-{package}"
    subprocess.run(["dpkg-deb", "-x", str(deb), str(root)], check=True)
    deb.unlink()
    (vmlinuz,) = (root / "boot").glob("vmlinuz-*")
    version = vmlinuz.name.removeprefix("vmlinuz-")
    return Kernel(version, vmlinuz, _modules_dir(root, version))


def _kernel_package() -> str:
    """linux-image-amd64 is a metapackage: the real one is its linux-image-* dependency."""
    for attempt in range(2):
        result = subprocess.run(["apt-cache", "depends", "linux-image-amd64"],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for line in result.stdout.splitlines():
            name = line.strip().removeprefix("Depends:").strip()
            if line.strip().startswith("Depends:") and name.startswith("linux-image-"):
                return name
        if attempt == 0:
            _apt(["apt-get", "update", "-qq"])
    raise VmError(f"cannot find Debian's kernel package (apt-cache depends linux-image-amd64):\n"
                  f"{result.stdout[-2000:]}")


def _modules_dir(root: Path, version: str) -> Path:
    """Copies the needed modules, flat, next to the unpacked package; checks none is missing."""
    flat = root / "pab-modules"
    if not all((flat / f"{name}.ko").exists() for name in MODULES):
        flat.mkdir(exist_ok=True)
        found = {path.name[: -len(".ko")]: path for path in (root / "lib/modules" / version).rglob("*.ko")}
        missing = [name for name in MODULES if name not in found]
        if missing:
            raise VmError(f"kernel {version} lacks the modules {', '.join(missing)}")
        for name in MODULES:
            shutil.copyfile(found[name], flat / f"{name}.ko")
    return flat


# -- the initramfs ---------------------------------------------------------------------------


def initramfs(kernel: Kernel, path: Path) -> Path:
    """Writes a gzipped newc cpio: /init, /bin/busybox and the modules. Rebuilt every run (fast)."""
    entries: list[tuple[str, int, bytes]] = [
        ("bin", 0o040755, b""),
        ("lib", 0o040755, b""),
        ("lib/modules", 0o040755, b""),
        ("init", 0o100755, INIT.read_bytes()),
        ("bin/busybox", 0o100755, BUSYBOX.read_bytes()),
    ]
    for name in MODULES:
        entries.append((f"lib/modules/{name}.ko", 0o100644, (kernel.modules / f"{name}.ko").read_bytes()))
    with gzip.open(path, "wb", compresslevel=1) as out:
        for inode, (name, mode, data) in enumerate(entries, start=1):
            _cpio_entry(out, name, mode, data, inode)
        _cpio_entry(out, "TRAILER!!!", 0, b"", 0)
    return path


def _cpio_entry(out, name: str, mode: int, data: bytes, inode: int) -> None:
    encoded = name.encode() + b"\0"
    fields = (inode, mode, 0, 0, 2 if mode & 0o040000 else 1, 0, len(data), 0, 0, 0, 0, len(encoded), 0)
    header = b"070701" + b"".join(b"%08X" % value for value in fields)
    out.write(header + encoded + b"\0" * (-(len(header) + len(encoded)) % 4))
    out.write(data + b"\0" * (-len(data) % 4))


# -- running ---------------------------------------------------------------------------------


def kvm_usable() -> bool:
    return os.access("/dev/kvm", os.R_OK | os.W_OK)


def run(job: str, out_dir: Path, cache: Path, timeout_s: float) -> Outcome:
    """Boots the micro-VM, runs the shell script `job` in it, and returns its exit status.

    The guest's console (the job's output) is copied to stdout as it comes.
    """
    ensure_host_tools()
    guest_kernel = kernel(cache)
    image = initramfs(guest_kernel, cache / "initramfs.cpio.gz")
    out_dir = out_dir.resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "job.sh").write_text(job)
    status_file = out_dir / "job.status"
    status_file.unlink(missing_ok=True)

    started = time.monotonic()
    if kvm_usable():
        say(f"booting the micro-VM (kernel {guest_kernel.version}) with KVM")
        outcome = _boot(guest_kernel, image, out_dir, "KVM", timeout_s, probe_s=KVM_PROBE_S)
        if outcome is None:
            say(f"KVM showed no sign of life within {KVM_PROBE_S:.0f} s: "
                "falling back to software emulation (TCG)")
    else:
        say("/dev/kvm is not usable here: software emulation (TCG)")
        outcome = None
    if outcome is None:
        say(f"booting the micro-VM (kernel {guest_kernel.version}) under TCG")
        outcome = _boot(guest_kernel, image, out_dir, "TCG (software emulation)", timeout_s, probe_s=None)
    assert outcome is not None
    outcome.total_s = time.monotonic() - started
    if not status_file.exists():
        raise VmError("the micro-VM stopped without the job's exit status (see its console above)")
    outcome.status = int(status_file.read_text().strip() or "1")
    return outcome


def _boot(k: Kernel, image: Path, out_dir: Path, accel: str, timeout_s: float,
          probe_s: float | None) -> Outcome | None:
    accel_args = ["-enable-kvm", "-cpu", "host"] if accel == "KVM" else ["-accel", "tcg", "-cpu", "max"]
    cpus = max(1, min(4, os.cpu_count() or 1))
    command = [
        "qemu-system-x86_64", *accel_args, "-m", "2048", "-smp", str(cpus),
        "-nodefaults", "-no-user-config",  # no VGA, no NIC and its option ROM
        "-kernel", str(k.boot_image), "-initrd", str(image),
        # mitigations=off: nothing to protect in a throwaway guest, and KPTI & co. cost a lot
        # under emulation.
        "-append", f"console=ttyS0 quiet panic=-1 mitigations=off pab_out={out_dir}",
        "-display", "none", "-no-reboot", "-serial", "stdio", "-monitor", "none",
        "-virtfs", "local,path=/,mount_tag=host,security_model=none,readonly=on,multidevs=remap",
        "-virtfs", f"local,path={out_dir},mount_tag=out,security_model=none",
    ]
    launched = time.monotonic()
    qemu = subprocess.Popen(command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)
    lines: queue.Queue[bytes | None] = queue.Queue()

    def pump() -> None:
        for line in qemu.stdout:
            lines.put(line)
        lines.put(None)

    threading.Thread(target=pump, daemon=True).start()
    alive = False
    boot_s = first_test_s = 0.0
    deadline = launched + (probe_s if probe_s is not None else BOOT_TIMEOUT_S)
    while True:
        try:
            line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            qemu.kill()
            qemu.wait()
            if probe_s is not None and not alive:
                return None  # the caller falls back to TCG
            what = "finish the job" if boot_s else "boot"
            raise VmError(f"the micro-VM ({accel}) did not {what} in time; stopped it")
        if line is None:
            break
        text = line.decode(errors="replace")
        sys.stdout.write(text)
        sys.stdout.flush()
        if text.startswith("pab-vm: init") and not alive:
            alive = True
            deadline = launched + BOOT_TIMEOUT_S
        elif text.startswith("pab-vm: job starting") and not boot_s:
            boot_s = time.monotonic() - launched
            say(f"micro-VM booted in {boot_s:.1f} s ({accel}); the job runs")
            deadline = launched + timeout_s
        elif FIRST_TEST_MARKER in text and boot_s and not first_test_s:
            first_test_s = time.monotonic() - launched
            (out_dir / "vm-boot.txt").write_text(
                f"boot {boot_s:.1f} s, first test {first_test_s:.1f} s after QEMU started ({accel})\n")
    qemu.wait()
    return Outcome(status=-1, accel=accel, boot_s=boot_s, total_s=0.0)
