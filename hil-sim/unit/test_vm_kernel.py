"""The guest kernel's modules: which to load, in which order, from the package's own modules.dep,
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

# A modules.dep in the style of a 6.12 kernel: fscache folded into netfs, xz-compressed modules,
# virtio built in, dependencies listed in modprobe's order (not necessarily load order).
MODULES_DEP = """\
kernel/drivers/virtio/virtio_pci.ko.xz: kernel/drivers/virtio/virtio_pci_modern_dev.ko.xz kernel/drivers/virtio/virtio_pci_legacy_dev.ko.xz kernel/drivers/virtio/virtio_ring.ko.xz
kernel/drivers/virtio/virtio_pci_modern_dev.ko.xz:
kernel/drivers/virtio/virtio_pci_legacy_dev.ko.xz:
kernel/drivers/virtio/virtio_ring.ko.xz:
kernel/net/9p/9pnet_virtio.ko.xz: kernel/net/9p/9pnet.ko.xz kernel/drivers/virtio/virtio_ring.ko.xz
kernel/net/9p/9pnet.ko.xz:
kernel/fs/9p/9p.ko.xz: kernel/fs/netfs/netfs.ko.xz kernel/net/9p/9pnet.ko.xz
kernel/fs/netfs/netfs.ko.xz:
kernel/net/can/can-raw.ko.xz: kernel/net/can/can.ko.xz
kernel/net/can/can.ko.xz:
kernel/net/can/can-gw.ko.xz: kernel/net/can/can.ko.xz
kernel/drivers/net/can/vcan.ko.xz:
kernel/drivers/net/can/slcan/slcan.ko.xz: kernel/drivers/net/can/dev/can-dev.ko.xz
kernel/drivers/net/can/dev/can-dev.ko.xz:
kernel/drivers/unrelated.ko.xz:
"""
BUILTIN = "kernel/drivers/virtio/virtio.ko\n"


def make_tree(root: Path, dep: str = MODULES_DEP, compress=lzma.compress) -> Path:
    base = root / "lib/modules" / VERSION
    base.mkdir(parents=True)
    (base / "modules.dep").write_text(dep)
    (base / "modules.builtin").write_text(BUILTIN)
    for line in dep.splitlines():
        path = line.partition(":")[0]
        file = base / path
        file.parent.mkdir(parents=True, exist_ok=True)
        file.write_bytes(compress(b"\x7fELF module " + path.encode()))
    return root


def test_every_module_comes_after_its_dependencies(tmp_path):
    modules, builtin = k._index([make_tree(tmp_path)], VERSION)
    order = k.load_order(modules, builtin)
    assert set(order) >= {k._norm(name) for name in k.WANTED}
    assert "unrelated" not in order and "virtio" not in order  # not wanted; built in
    for name in order:
        for dependency in modules[name][1]:
            assert order.index(dependency) < order.index(name), (dependency, name)


def test_modules_are_decompressed_for_busybox_insmod(tmp_path):
    tree = make_tree(tmp_path / "pkg")
    plain = k._plain_modules([tree], VERSION, tmp_path / "plain")
    assert [path.stem for path in plain] == k.load_order(*k._index([tree], VERSION))
    for path in plain:
        assert path.suffix == ".ko" and path.read_bytes().startswith(b"\x7fELF module kernel/")


def test_gzip_and_plain_modules_too(tmp_path):
    for compress, suffix in ((gzip.compress, ".ko.gz"), (lambda data: data, ".ko")):
        root = tmp_path / suffix
        tree = make_tree(root, MODULES_DEP.replace(".ko.xz", suffix), compress)
        plain = k._plain_modules([tree], VERSION, root / "plain")
        assert all(path.read_bytes().startswith(b"\x7fELF") for path in plain)


def test_a_kernel_without_vcan_is_named(tmp_path):
    dep = "\n".join(line for line in MODULES_DEP.splitlines() if "vcan" not in line) + "\n"
    tree = make_tree(tmp_path, dep)
    assert k._missing([tree], VERSION) == ["vcan"]


def test_modules_split_over_two_packages_are_found(tmp_path):
    # Ubuntu: the image package's modules.dep lists files a modules package carries.
    image = make_tree(tmp_path / "image")
    extra = tmp_path / "extra"
    moved = image / "lib/modules" / VERSION / "kernel/drivers/net/can/vcan.ko.xz"
    target = extra / "lib/modules" / VERSION / "kernel/drivers/net/can/vcan.ko.xz"
    target.parent.mkdir(parents=True)
    moved.rename(target)
    assert k._missing([image], VERSION) == ["vcan"]
    assert k._missing([image, extra], VERSION) == []


def test_a_dependency_cycle_is_an_error_not_a_hang(tmp_path):
    dep = MODULES_DEP.replace("kernel/net/can/can.ko.xz:\n",
                              "kernel/net/can/can.ko.xz: kernel/net/can/can-raw.ko.xz\n")
    with pytest.raises(k.KernelError, match="cycle: can_raw -> can -> can_raw"):
        k.load_order(*k._index([make_tree(tmp_path, dep)], VERSION))


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
