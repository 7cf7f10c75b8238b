"""The micro-VM's initramfs: /init (the script beside this file), a static busybox, the modules.

Busybox comes from the distribution's `busybox-static` package, unpacked into the cache, whatever
the host has installed: Debian's plain `busybox` package is dynamically linked and would not run
in an initramfs without a libc.
"""

from __future__ import annotations

import gzip
from pathlib import Path

from . import debian
from .kernel import Kernel

INIT = Path(__file__).with_name("init")
# The init script insmods the modules named in this file, one per line, in order.
LOAD_ORDER = "lib/modules/load-order"


class InitramfsError(RuntimeError):
    pass


def static_busybox(cache: Path) -> Path:
    """A statically linked busybox from the `busybox-static` package (downloaded once)."""
    root = debian.fetch_and_unpack("busybox-static", cache)
    for candidate in (root / "bin/busybox", root / "usr/bin/busybox"):
        if candidate.exists():
            if not is_static_elf(candidate.read_bytes()):
                raise InitramfsError(f"{candidate} is not a static ELF executable")
            return candidate
    raise InitramfsError(f"busybox-static unpacked into {root} holds no bin/busybox")


def is_static_elf(data: bytes) -> bool:
    """Whether `data` is an ELF executable without a program interpreter (PT_INTERP)."""
    if data[:4] != b"\x7fELF" or len(data) < 64:
        return False
    is_64 = data[4] == 2
    little = data[5] == 1
    order = "little" if little else "big"

    def field(offset: int, size: int) -> int:
        return int.from_bytes(data[offset:offset + size], order)

    if is_64:
        phoff, phentsize, phnum = field(0x20, 8), field(0x36, 2), field(0x38, 2)
    else:
        phoff, phentsize, phnum = field(0x1C, 4), field(0x2A, 2), field(0x2C, 2)
    for index in range(phnum):
        if field(phoff + index * phentsize, 4) == 3:  # PT_INTERP
            return False
    return True


def build(kernel: Kernel, busybox: Path, path: Path) -> Path:
    """Writes a gzipped newc cpio: /init, /bin/busybox, the modules and their load order.
    Rebuilt every run (fast)."""
    entries: list[tuple[str, int, bytes]] = [
        ("bin", 0o040755, b""),
        ("lib", 0o040755, b""),
        ("lib/modules", 0o040755, b""),
        ("init", 0o100755, INIT.read_bytes()),
        ("bin/busybox", 0o100755, busybox.read_bytes()),
    ]
    names = []
    for module in kernel.modules:
        entries.append((f"lib/modules/{module.name}", 0o100644, module.read_bytes()))
        names.append(module.stem)
    entries.append((LOAD_ORDER, 0o100644, ("\n".join(names) + "\n").encode()))
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
