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
