"""Shared fixtures: the bus interface, the results directory, and closed-loop sessions.

The tests that need a bus fail (never skip) when the interface is missing: run them through
`hil-sim/run-hil`, which provides one (the machine's vcan0, or a micro-VM's).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from pab_hil import speed
from pab_hil.nodes import REPO, pushed_within_budget, stop_leftovers
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


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item, nextitem):
    """After each test's own teardown: no node of it stays on the bus. A failed test may leave its
    nodes running (a failure between start and stop); they are stopped here, so that the next
    test's nodes are alone. A test that passed and left nodes running has a bug of its own: its
    teardown fails, naming them."""
    result = yield
    leftovers = stop_leftovers()
    failed = any(getattr(item, f"rep_{when}", None) is not None
                 and getattr(item, f"rep_{when}").failed for when in ("setup", "call"))
    if leftovers and not failed:
        raise AssertionError("the test left nodes running on the bus: " + ", ".join(leftovers))
    return result


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    """Keeps each phase's report on the item (`rep_setup`, `rep_call`) for the teardown above."""
    report = yield
    setattr(item, f"rep_{report.when}", report)
    return report


def pytest_addoption(parser):
    parser.addoption("--iface", default=os.environ.get("PAB_HIL_IFACE", "vcan0"),
                     help="SocketCAN interface for the HIL tests (default: vcan0)")
    parser.addoption("--fd-iface", default=os.environ.get("PAB_HIL_FD_IFACE", "vcan1"),
                     help="SocketCAN interface with MTU 72 for the CAN FD tests (default: vcan1)")
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
def fd_iface(request) -> str:
    """The CAN FD tests' bus: an interface that carries CAN FD frames (MTU 72)."""
    name = request.config.getoption("--fd-iface")
    mtu = Path(f"/sys/class/net/{name}/mtu")
    if not mtu.exists():
        pytest.fail(f"no CAN interface {name!r} on this machine: run the suite with "
                    "hil-sim/run-hil (it makes one with MTU 72, in a micro-VM if need be)")
    if int(mtu.read_text()) != 72:
        pytest.fail(f"{name} carries classic CAN only (MTU {mtu.read_text().strip()}): the CAN FD "
                    f"tests need MTU 72 (`ip link set {name} down; ip link set {name} mtu 72; "
                    f"ip link set {name} up`)")
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
def session_for(iface, out_dir, bound):
    """session_for(person, network=...) -> a started Session, closed after the test. Its table
    transfers are bounds of the test (`pushed_within_budget`)."""
    sessions = []

    def start(person, **kwargs) -> Session:
        session = Session(iface, out_dir, person=person, **kwargs)
        sessions.append(session)
        session.start()
        pushed_within_budget(bound, session.pushed)
        return session

    yield start
    for session in sessions:
        session.close()


@pytest.fixture
def figures(hil_out):
    """figures(name, {...}): writes one figure record (docs/figures.md), printed by run-hil."""
    directory = hil_out / "figures"

    def write(name: str, values: dict) -> None:
        directory.mkdir(parents=True, exist_ok=True)
        (directory / f"{name}.json").write_text(json.dumps(values) + "\n")

    return write


class Machine:
    """This machine's speed against the reference's (pab_hil.speed): `allow(s)` is an allowance
    of `s` seconds on the reference, scaled by `factor`; `board_allow(s, board)` one that the
    emulated board's line adds, scaled by its own measure."""

    def __init__(self) -> None:
        self.factor = speed.machine_factor()

    def allow(self, seconds: float) -> float:
        return seconds * self.factor

    def board_allow(self, seconds: float, board) -> float:
        return seconds * max(self.factor, speed.board_factor(board.boot_s))


@pytest.fixture(scope="session")
def machine(hil_out) -> Machine:
    found = Machine()
    directory = hil_out / "figures"
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "machine.json").write_text(json.dumps({
        "vm_boot_s": os.environ.get(speed.VM_BOOT_ENV, "none (this machine's vcan0)"),
        "factor": round(found.factor, 2),
    }) + "\n")
    return found


BOUNDS = "bounds.jsonl"


@pytest.fixture
def bound(hil_out, request):
    """bound(name, measured, most=..., least=..., unit="s", detail=...): a timing bound of the
    test. Asserts least <= measured <= most (`detail` joins the failure's message), and records the bound with its margin (how far the measure stayed
    from the nearer limit) in the results directory, one JSON line each, which run-hil prints
    after the suite: a shrinking margin shows before it fails."""

    def check(name: str, measured: float, *, most: float | None = None,
              least: float | None = None, unit: str = "s", detail: object = "") -> None:
        if most is None and least is None:
            raise ValueError(f"bound {name!r}: give it a limit (most=, least= or both)")
        margins = [m for m in ((None if most is None else most - measured),
                               (None if least is None else measured - least)) if m is not None]
        margin = min(margins)
        # The share of an upper bound left unused (a latency's headroom); none for a lower bound,
        # whose distance from 0 says nothing.
        upper = most is not None and most > 0 and most - measured == margin
        record = {"test": request.node.name, "name": name, "measured": measured, "least": least,
                  "most": most, "unit": unit, "margin": margin,
                  "margin_of_limit": margin / most if upper else None}
        with open(hil_out / BOUNDS, "a") as f:
            f.write(json.dumps(record) + "\n")
        within = " and ".join(part for part in (
            None if least is None else f">= {least:.4g}", None if most is None else f"<= {most:.4g}")
            if part)
        assert margin >= 0, (f"{name}: {measured:.4g} {unit}, outside its bound ({within} {unit})"
                             + (f"; {detail}" if detail else ""))

    return check

