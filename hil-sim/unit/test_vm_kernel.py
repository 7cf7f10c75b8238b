"""The guest kernel's modules: which to load, in which order, from each module's own .modinfo,
whatever the kernel version calls them or however it compresses them; and the static-busybox
check. Synthetic package trees: no download."""

from __future__ import annotations

import gzip
import lzma
import struct
from pathlib import Path

import pytest

from pab_hil.vm import initramfs, kernel as k

VERSION = "6.99.0-1-amd64"

# Modules in the style of a 6.12 kernel: fscache folded into netfs, virtio built in, xz-compressed
# files; each one's dependencies, as its .modinfo `depends=` lists them.
MODULES = {
    "kernel/drivers/virtio/virtio_pci": "virtio_pci_modern_dev,virtio_pci_legacy_dev,virtio_ring",
    "kernel/drivers/virtio/virtio_pci_modern_dev": "",
    "kernel/drivers/virtio/virtio_pci_legacy_dev": "",
    "kernel/drivers/virtio/virtio_ring": "",
    "kernel/net/9p/9pnet_virtio": "9pnet,virtio_ring",
    "kernel/net/9p/9pnet": "",
    "kernel/fs/9p/9p": "netfs,9pnet",
    "kernel/fs/netfs/netfs": "",
    "kernel/net/can/can-raw": "can",
    "kernel/net/can/can": "",
    "kernel/net/can/can-gw": "can",
    "kernel/net/can/can-isotp": "can",
    "kernel/drivers/net/can/vcan": "",
    "kernel/drivers/net/can/slcan/slcan": "can-dev",
    "kernel/drivers/net/can/dev/can-dev": "",
    "kernel/drivers/unrelated": "",
}
BUILTIN = "kernel/drivers/virtio/virtio.ko\n"


def module_elf(depends: str) -> bytes:
    """A minimal ELF64 relocatable with a .modinfo section, as modpost writes it."""
    modinfo = b"license=GPL\0" + b"depends=" + depends.encode() + b"\0" + b"vermagic=6.99\0"
    shstrtab = b"\0.modinfo\0.shstrtab\0"
    body = modinfo + shstrtab
    shoff = 64 + len(body)
    header = bytearray(64)
    header[:7] = b"\x7fELF\x02\x01\x01"
    struct.pack_into("<HHI", header, 0x10, 1, 62, 1)  # ET_REL, x86-64
    struct.pack_into("<Q", header, 0x28, shoff)
    struct.pack_into("<HHHHHH", header, 0x34, 64, 0, 0, 64, 3, 2)
    def section(name: int, kind: int, offset: int, size: int) -> bytes:
        return struct.pack("<IIQQQQIIQQ", name, kind, 0, 0, offset, size, 0, 0, 1, 0)
    sections = (section(0, 0, 0, 0) + section(1, 1, 64, len(modinfo))
                + section(10, 3, 64 + len(modinfo), len(shstrtab)))
    return bytes(header) + body + sections


def make_tree(root: Path, suffix: str = ".ko.xz", compress=lzma.compress,
              modules: dict[str, str] = MODULES) -> Path:
    base = root / "lib/modules" / VERSION
    base.mkdir(parents=True)
    (base / "modules.builtin").write_text(BUILTIN)
    for path, depends in modules.items():
        file = base / (path + suffix)
        file.parent.mkdir(parents=True, exist_ok=True)
        file.write_bytes(compress(module_elf(depends)))
    return root


def test_every_module_comes_after_its_dependencies(tmp_path):
    files, builtin = k._index([make_tree(tmp_path)], VERSION)
    order = k.load_order(files, builtin)
    assert set(order) >= {k._norm(name) for name in k.WANTED}
    assert "unrelated" not in order and "virtio" not in order  # not wanted; built in
    for name in order:
        for dependency in k.modinfo_depends(k._decompress(files[name])):
            assert order.index(dependency) < order.index(name), (dependency, name)


def test_modules_are_decompressed_for_busybox_insmod(tmp_path):
    tree = make_tree(tmp_path / "pkg")
    plain = k._plain_modules([tree], VERSION, tmp_path / "plain")
    assert [path.stem for path in plain] == k.load_order(*k._index([tree], VERSION))
    for path in plain:
        assert path.suffix == ".ko" and path.read_bytes().startswith(b"\x7fELF")


def test_gzip_and_plain_modules_too(tmp_path):
    for compress, suffix in ((gzip.compress, ".ko.gz"), (lambda data: data, ".ko")):
        root = tmp_path / suffix
        plain = k._plain_modules([make_tree(root, suffix, compress)], VERSION, root / "plain")
        assert all(path.read_bytes().startswith(b"\x7fELF") for path in plain)


def test_a_kernel_without_vcan_is_named(tmp_path):
    modules = {path: deps for path, deps in MODULES.items() if "vcan" not in path}
    assert k._missing([make_tree(tmp_path, modules=modules)], VERSION) == ["vcan"]


def test_modules_split_over_two_packages_are_found(tmp_path):
    # Ubuntu: the kernel's modules come in more than one package.
    image = make_tree(tmp_path / "image")
    extra = tmp_path / "extra"
    moved = image / "lib/modules" / VERSION / "kernel/drivers/net/can/vcan.ko.xz"
    target = extra / "lib/modules" / VERSION / "kernel/drivers/net/can/vcan.ko.xz"
    target.parent.mkdir(parents=True)
    moved.rename(target)
    assert k._missing([image], VERSION) == ["vcan"]
    assert k._missing([image, extra], VERSION) == []
    assert "vcan" in k.load_order(*k._index([image, extra], VERSION))


def test_a_dependency_cycle_is_an_error_not_a_hang(tmp_path):
    modules = dict(MODULES, **{"kernel/net/can/can": "can-raw"})
    with pytest.raises(k.KernelError, match="cycle: can_raw -> can -> can_raw"):
        k.load_order(*k._index([make_tree(tmp_path, modules=modules)], VERSION))


def test_a_missing_dependency_is_named(tmp_path):
    modules = dict(MODULES, **{"kernel/net/can/can-gw": "can,nosuch"})
    with pytest.raises(k.KernelError, match="module nosuch is neither"):
        k.load_order(*k._index([make_tree(tmp_path, modules=modules)], VERSION))


def elf64(program_header_types: list[int]) -> bytes:
    header = bytearray(64)
    header[:6] = b"\x7fELF\x02\x01"
    struct.pack_into("<QHHH", header, 0x20, 64, 0, 0, 0)  # e_phoff
    struct.pack_into("<H", header, 0x36, 56)  # e_phentsize
    struct.pack_into("<H", header, 0x38, len(program_header_types))  # e_phnum
    table = b"".join(struct.pack("<I", kind) + bytes(52) for kind in program_header_types)
    return bytes(header) + table


def test_static_elf_check():
    assert initramfs.is_static_elf(elf64([1, 1, 4]))
    assert not initramfs.is_static_elf(elf64([6, 3, 1]))  # PT_PHDR, PT_INTERP: dynamic
    assert not initramfs.is_static_elf(b"#!/bin/sh\n")
    assert not initramfs.is_static_elf(Path("/bin/sh").read_bytes())  # Debian's dash: dynamic
