"""The host side of the emulated board in the micro-VM (pab_hil.board.HostBoards), with a
stand-in for qemu-system-arm and a unix socket standing in for the micro-VM's serial port: the
requests the guest sends (start, reset, stop), what each answers, the board's QEMU command line,
and a new connection after the micro-VM's QEMU went away. Also the micro-VM's command line with
the serial ports. No QEMU: these run on any host."""

from __future__ import annotations

import os
import socket
import stat
import sys
import time
from pathlib import Path

import pytest

from pab_hil.board import HostBoards
from pab_hil.vm.boot import TCG, _command

STAND_IN = """#!{python}
import os, sys, time
with open(os.environ["FAKE_ARM_LOG"], "a") as log:
    log.write(" ".join(sys.argv[1:]) + "\\n")
time.sleep(60)
"""


@pytest.fixture
def boards(tmp_path, monkeypatch):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    stand_in = bin_dir / "qemu-system-arm"
    stand_in.write_text(STAND_IN.format(python=sys.executable))
    stand_in.chmod(stand_in.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("FAKE_ARM_LOG", str(tmp_path / "arm-invocations"))
    service = HostBoards()
    yield service
    service.close()


class Guest:
    """The micro-VM's end of the control port: QEMU listens, the service connects."""

    def __init__(self, path: Path) -> None:
        self.server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.server.bind(str(path))
        self.server.listen(1)
        self.server.settimeout(10)
        self.conn, _ = self.server.accept()
        self.conn.settimeout(10)

    def ask(self, line: str) -> str:
        self.conn.sendall(line.encode() + b"\n")
        answer = b""
        while not answer.endswith(b"\n"):
            answer += self.conn.recv(256)
        return answer.decode().strip()

    def close(self) -> None:
        self.conn.close()
        self.server.close()


def wait_for(condition, what: str, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


def test_start_reset_stop_and_the_boards_command_line(boards, tmp_path):
    boards.start()
    guest = Guest(boards.control)
    try:
        elf, log = tmp_path / "pab-fw-an386", tmp_path / "arm.log"
        answer = guest.ask(f"start {elf} {log}")
        assert answer.startswith("ok "), answer
        pid = int(answer.split()[1])
        invocations = tmp_path / "arm-invocations"
        wait_for(invocations.exists, "the stand-in never ran")
        arguments = invocations.read_text().split()
        assert arguments[:2] == ["-M", "mps2-an386"]
        assert arguments[arguments.index("-serial") + 1] == f"unix:{boards.uart}"
        assert arguments[arguments.index("-kernel") + 1] == str(elf)
        assert "enable=on,target=native" in arguments  # semihosting: the board's log
        # The stand-in serves no monitor: the reset is refused with the reason, not hung.
        answer = guest.ask("reset")
        assert answer.startswith("error "), answer
        assert guest.ask("stop") == "ok"
        wait_for(lambda: not Path(f"/proc/{pid}").exists()
                 or "zombie" in Path(f"/proc/{pid}/status").read_text().lower(),
                 "the board's QEMU still runs after stop")
        assert guest.ask("reset") == "error the board is not running"
        assert guest.ask("fly").startswith("error unknown request")
        # `ahead` (a test that times the board) is the only word a start may end with.
        assert guest.ask(f"start {elf} {log} sideways").startswith("error unknown request")
        answer = guest.ask(f"start {elf} {log} ahead")
        assert answer.startswith("ok "), answer
        assert guest.ask("stop") == "ok"
        # Behind the bootloader: the factory image and the key page planted; a `boot` without
        # both is refused.
        factory, page = tmp_path / "v1.bin", tmp_path / "page.bin"
        factory.write_bytes(bytes(8))
        page.write_bytes(bytes(8))
        invocations.unlink()
        answer = guest.ask(f"start {elf} {log} ahead boot {factory} {page}")
        assert answer.startswith("ok "), answer
        wait_for(invocations.exists, "the stand-in never ran")
        arguments = invocations.read_text().split()
        assert f"loader,file={factory},addr=0x100000,force-raw=on" in arguments, arguments
        assert guest.ask("stop") == "ok"
        assert guest.ask(f"start {elf} {log} boot {factory}").startswith("error unknown request")
    finally:
        guest.close()


def test_the_service_connects_again_to_a_new_micro_vm(boards):
    # A KVM attempt that falls back to TCG starts a second QEMU on the same socket path.
    boards.start()
    first = Guest(boards.control)
    assert first.ask("stop") == "ok"
    first.close()
    boards.control.unlink()
    second = Guest(boards.control)
    try:
        assert second.ask("stop") == "ok"
    finally:
        second.close()


def test_the_micro_vm_gets_the_serial_ports_after_its_console(tmp_path):
    command = _command(Path("vmlinux"), Path("initrd"), tmp_path, TCG,
                       [tmp_path / "uart.sock", tmp_path / "control.sock"])
    serials = [command[i + 1] for i, arg in enumerate(command) if arg == "-serial"]
    assert serials == ["stdio", "chardev:serial1", "chardev:serial2"]
    chardevs = [command[i + 1] for i, arg in enumerate(command) if arg == "-chardev"]
    assert chardevs == [
        f"socket,id=serial1,path={tmp_path / 'uart.sock'},server=on,wait=off",
        f"socket,id=serial2,path={tmp_path / 'control.sock'},server=on,wait=off",
    ]
