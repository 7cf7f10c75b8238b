"""Shared fixtures: the bus interface, the results directory, and closed-loop sessions.

The tests that need a bus fail (never skip) when the interface is missing: run them through
`hil-sim/run-hil`, which provides one (the machine's vcan0, or a micro-VM's).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from pab_hil.nodes import REPO
from pab_hil.scenario import Session


_first_test_seen = False


def pytest_runtest_setup(item):
    """Marks the first test on the terminal: run-hil times the micro-VM's boot up to here."""
    global _first_test_seen
    if not _first_test_seen:
        _first_test_seen = True
        capture = item.config.pluginmanager.get_plugin("capturemanager")
        with capture.global_and_fixture_disabled():
            print(f"\npab-hil: first test starting ({item.nodeid})", flush=True)


def pytest_addoption(parser):
    parser.addoption("--iface", default=os.environ.get("PAB_HIL_IFACE", "vcan0"),
                     help="SocketCAN interface for the HIL tests (default: vcan0)")
    parser.addoption("--hil-out", default=str(REPO / "target" / "hil"),
                     help="directory for logs, plots and figures (default: target/hil)")


@pytest.fixture(scope="session")
def iface(request) -> str:
    name = request.config.getoption("--iface")
    if not Path(f"/sys/class/net/{name}").exists():
        pytest.fail(f"no CAN interface {name!r} on this machine: run the suite with "
                    "hil-sim/run-hil (it makes one, in a micro-VM if need be)")
    return name


@pytest.fixture(scope="session")
def hil_out(request) -> Path:
    path = Path(request.config.getoption("--hil-out")).resolve()
    path.mkdir(parents=True, exist_ok=True)
    return path


@pytest.fixture
def out_dir(hil_out, request) -> Path:
    path = hil_out / request.node.name
    path.mkdir(parents=True, exist_ok=True)
    return path


@pytest.fixture
def session_for(iface, out_dir):
    """session_for(person, network=...) -> a started Session, closed after the test."""
    sessions = []

    def start(person, **kwargs) -> Session:
        session = Session(iface, out_dir, person=person, **kwargs)
        sessions.append(session)
        session.start()
        return session

    yield start
    for session in sessions:
        session.close()


@pytest.fixture
def figures(hil_out):
    """figures(name, {...}): writes one figure record for the README, printed by run-hil."""
    directory = hil_out / "figures"

    def write(name: str, values: dict) -> None:
        directory.mkdir(parents=True, exist_ok=True)
        (directory / f"{name}.json").write_text(json.dumps(values) + "\n")

    return write
