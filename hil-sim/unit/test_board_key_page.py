"""The board's QEMU command line plants the key page of $PAB_KEY_PAGE (docs/keys.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from pab_hil.board import BoardError, qemu_command


def test_no_key_page_without_the_variable(monkeypatch):
    monkeypatch.delenv("PAB_KEY_PAGE", raising=False)
    command = qemu_command(Path("fw"), "pty", Path("monitor.sock"))
    assert not any(argument.startswith("loader,") for argument in command)


def test_the_key_page_is_loaded_at_the_boards_address(monkeypatch, tmp_path):
    page = tmp_path / "node1.keypage.bin"
    page.write_bytes(b"PABK" + bytes(28))
    monkeypatch.setenv("PAB_KEY_PAGE", str(page))
    command = qemu_command(Path("fw"), "pty", Path("monitor.sock"))
    device = command[command.index("-device") + 1]
    assert device == f"loader,file={page},addr=0x4e000,force-raw=on"


def test_a_missing_key_page_is_an_error_naming_it(monkeypatch, tmp_path):
    monkeypatch.setenv("PAB_KEY_PAGE", str(tmp_path / "missing.bin"))
    with pytest.raises(BoardError, match="missing.bin: no such file"):
        qemu_command(Path("fw"), "pty", Path("monitor.sock"))


def test_behind_the_bootloader_the_factory_image_and_key_page_are_planted(tmp_path):
    from pab_hil.board import BehindBootloader
    factory, page = tmp_path / "v1.bin", tmp_path / "page.bin"
    factory.write_bytes(bytes(64))
    page.write_bytes(bytes(112))
    command = qemu_command(Path("boot.elf"), "pty", Path("monitor.sock"),
                           BehindBootloader(factory, page))
    assert command[command.index("-kernel") + 1] == "boot.elf"
    devices = [command[i + 1] for i, word in enumerate(command) if word == "-device"]
    assert devices == [f"loader,file={factory},addr=0x100000,force-raw=on",
                       f"loader,file={page},addr=0x4e000,force-raw=on"]
    with pytest.raises(BoardError, match="missing.bin: no such file"):
        qemu_command(Path("boot.elf"), "pty", Path("monitor.sock"),
                     BehindBootloader(tmp_path / "missing.bin", page))
