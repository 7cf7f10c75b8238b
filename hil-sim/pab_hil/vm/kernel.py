"""The guest kernel: the distribution's own generic kernel, which carries SocketCAN as modules.

Which package: Debian's `linux-image-amd64` metapackage (its `linux-image-<version>` dependency);
on Ubuntu, whose kernels are split, `linux-image-virtual`/`linux-image-generic` plus the matching
`linux-modules-<version>` (and `-extra`) packages. Which modules, in which order: each module's own
`depends=` (its .modinfo section, what depmod reads; the packages ship no modules.dep, depmod
makes it at install time), not a list written for one kernel version (module names and
dependencies move between releases: `fscache` folded into `netfs` in 6.x, say), skipping what
`modules.builtin` says is built in. Compressed modules (`.ko.xz`, `.ko.zst`, `.ko.gz`) are
decompressed here, because busybox's insmod only loads plain ELF objects.
"""

from __future__ import annotations

import gzip
import lzma
import shutil
import subprocess
import zlib
from dataclasses import dataclass
from pathlib import Path

from . import debian

# What the guest needs, by module name; their dependencies are added from each module's depends=.
#   9p over virtio: the host's root and the results directory;
#   can-raw, vcan: the bus; can-gw and slcan: a board's serial-line CAN adapter, routed to vcan0;
#   can-isotp: the kernel's ISO-TP, the tests' independent sender of table images.
WANTED = ("virtio_pci", "9pnet_virtio", "9p", "can_raw", "vcan", "can_gw", "slcan", "can_isotp")

# Metapackages that pull the distribution's generic kernel, most specific first.
METAPACKAGES = ("linux-image-amd64", "linux-image-virtual", "linux-image-generic")


class KernelError(RuntimeError):
    pass


@dataclass
class Kernel:
    version: str
    vmlinuz: Path
    modules: list[Path]  # plain .ko files, in load order

    @property
    def boot_image(self) -> Path:
        """The uncompressed ELF kernel if it could be extracted, else the bzImage.

        QEMU boots an ELF vmlinux straight into 64-bit code (PVH, CONFIG_PVH=y in Debian's
        kernel): no real-mode setup and no decompression, which under emulation saves about 6 s
        of the boot."""
        vmlinux = self.vmlinuz.with_name("vmlinux")
        if not vmlinux.exists():
            extracted = extract_vmlinux(self.vmlinuz.read_bytes())
            if extracted is None:
                return self.vmlinuz
            vmlinux.write_bytes(extracted)
        return vmlinux


def extract_vmlinux(bzimage: bytes) -> bytes | None:
    """The ELF image inside a bzImage compressed with xz or gzip (what the stdlib can undo)."""
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


def prepare(cache: Path) -> Kernel:
    """The distribution's current generic kernel, unpacked into `cache` (downloaded once)."""
    arch = debian.architecture()
    if arch != "amd64":
        raise KernelError(f"the micro-VM runs an amd64 guest with qemu-system-x86_64; this host "
                          f"is {arch or 'not a Debian-based system'}: run the suite on a machine "
                          "with vcan instead")
    cache.mkdir(parents=True, exist_ok=True)
    image_package = _image_package()
    root = debian.fetch_and_unpack(image_package, cache)
    vmlinuzes = sorted((root / "boot").glob("vmlinuz-*"))
    if len(vmlinuzes) != 1:
        raise KernelError(f"{image_package} holds {len(vmlinuzes)} kernels in /boot, expected one")
    version = vmlinuzes[0].name.removeprefix("vmlinuz-")
    trees = [root]
    if _missing(trees, version):
        # Ubuntu: the image package has the kernel, the modules come in their own packages.
        for extra in (f"linux-modules-{version}", f"linux-modules-extra-{version}"):
            if debian.known(extra):
                trees.append(debian.fetch_and_unpack(extra, cache))
            if not _missing(trees, version):
                break
    missing = _missing(trees, version)
    if missing:
        raise KernelError(f"kernel {version} ({image_package}) lacks the modules "
                          f"{', '.join(missing)}: the micro-VM cannot have a vcan0")
    return Kernel(version, vmlinuzes[0], _plain_modules(trees, version, cache / f"modules-{version}"))


def _image_package() -> str:
    """The real package behind the first metapackage apt knows (after one `apt-get update` if
    none is known: a fresh machine's lists may be empty)."""
    for attempt in range(2):
        for meta in METAPACKAGES:
            for dependency in debian.depends(meta):
                if dependency.startswith("linux-image-") and dependency[len("linux-image-"):][:1].isdigit():
                    return dependency
        if attempt == 0:
            debian.update_once()
    raise KernelError("cannot find the distribution's kernel package (apt-cache depends "
                      f"{' / '.join(METAPACKAGES)} names no linux-image-<version>)")


def _norm(name: str) -> str:
    return name.replace("-", "_")


def _module_name(path: str) -> str:
    base = path.rsplit("/", 1)[-1]
    return _norm(base.split(".ko", 1)[0])


def modinfo_depends(module: bytes) -> list[str]:
    """The `depends=` list of a kernel module's .modinfo section (what modpost wrote and depmod
    reads): the modules it needs loaded first."""
    if module[:4] != b"\x7fELF" or module[4] != 2 or module[5] != 1:
        raise KernelError("not a little-endian ELF64 kernel module")

    def field(offset: int, size: int) -> int:
        return int.from_bytes(module[offset:offset + size], "little")

    shoff, shentsize, shnum, shstrndx = field(0x28, 8), field(0x3A, 2), field(0x3C, 2), field(0x3E, 2)
    sections = [(field(shoff + i * shentsize, 4), field(shoff + i * shentsize + 0x18, 8),
                 field(shoff + i * shentsize + 0x20, 8)) for i in range(shnum)]
    if shstrndx >= len(sections):
        raise KernelError("kernel module without a section name table")
    names_offset = sections[shstrndx][1]
    for name_at, offset, size in sections:
        end = module.find(b"\0", names_offset + name_at)
        if module[names_offset + name_at:end] == b".modinfo":
            for entry in module[offset:offset + size].split(b"\0"):
                if entry.startswith(b"depends="):
                    listed = entry[len(b"depends="):].decode()
                    return [_norm(name) for name in listed.split(",") if name]
            return []
    raise KernelError("kernel module without a .modinfo section")


def _index(trees: list[Path], version: str) -> tuple[dict[str, Path], set[str]]:
    """name -> module file, over every tree (the first tree that has it wins); the built-in
    names (modules.builtin: parts of the kernel image, nothing to load)."""
    files: dict[str, Path] = {}
    builtin: set[str] = set()
    for tree in trees:
        base = tree / "lib/modules" / version
        for path in sorted(base.rglob("*.ko*")):
            files.setdefault(_module_name(path.name), path)
        listed = base / "modules.builtin"
        if listed.exists():
            builtin.update(_module_name(line) for line in listed.read_text().split())
    return files, builtin


def _missing(trees: list[Path], version: str) -> list[str]:
    files, builtin = _index(trees, version)
    return [name for name in WANTED if name not in builtin and name not in files]


def load_order(files: dict[str, Path], builtin: set[str]) -> list[str]:
    """The wanted modules and their dependencies, each after everything it depends on."""
    order: list[str] = []
    seen: set[str] = set()

    def visit(name: str, chain: tuple[str, ...]) -> None:
        if name in seen or name in builtin:
            return
        if name in chain:
            raise KernelError(f"module dependencies form a cycle: {' -> '.join(chain + (name,))}")
        if name not in files:
            raise KernelError(f"module {name} is neither in the kernel's packages nor built in")
        for dependency in modinfo_depends(_decompress(files[name])):
            visit(dependency, chain + (name,))
        seen.add(name)
        order.append(name)

    for wanted in WANTED:
        visit(wanted, ())
    return order


def _plain_modules(trees: list[Path], version: str, into: Path) -> list[Path]:
    """The modules to load, decompressed into `into` as <name>.ko, in load order."""
    files, builtin = _index(trees, version)
    into.mkdir(parents=True, exist_ok=True)
    plain = []
    for name in load_order(files, builtin):
        target = into / f"{name}.ko"
        if not target.exists():
            target.write_bytes(_decompress(files[name]))
        plain.append(target)
    return plain


def _decompress(path: Path) -> bytes:
    data = path.read_bytes()
    suffix = path.suffix
    if suffix == ".ko":
        return data
    if suffix == ".xz":
        return lzma.decompress(data)
    if suffix == ".gz":
        return gzip.decompress(data)
    if suffix == ".zst":
        zstd = shutil.which("zstd")
        if zstd is None:
            raise KernelError(f"{path.name} is zstd-compressed and there is no `zstd` here "
                              "(apt-get install zstd)")
        return subprocess.run([zstd, "-dcq", str(path)], stdout=subprocess.PIPE, check=True).stdout
    raise KernelError(f"cannot load {path.name}: unknown module compression")
