"""The suite's timing bounds: the push times read from pabctl's output, the node's transfer budget,
and the margins over several runs (pab_hil.bounds)."""

from __future__ import annotations

import json

from pab_hil import bounds
from pab_hil.nodes import PushResult, transfer_budget

PUSH = """\
       arm  node  10  516 bytes in 84 ms (9 CAN FD frames)  ok: runs version 1 (stored)
      hand  node  11  1204 bytes in 1312 ms (173 classic CAN frames)  ok: runs version 1 (stored)
      gaze  node  12  80 bytes  FAILED: no answer
"""


def test_push_times_per_node_from_pabctls_lines():
    # A node pabctl reached no further than the transfer's start has no time: none listed.
    assert PushResult(0, PUSH).transfers() == {"arm": (516, 0.084), "hand": (1204, 1.312)}
    assert PushResult(0, PUSH).pushes() == {"arm": (516, 0.084, 9, "CAN FD"),
                                            "hand": (1204, 1.312, 173, "classic CAN")}
    assert PushResult(0, "").transfers() == {}


def test_the_nodes_transfer_budget_is_one_second_and_ten_ms_a_consecutive_frame():
    assert transfer_budget(6) == 1.0  # a single frame's worth: no consecutive frame
    assert abs(transfer_budget(516) - 1.73) < 1e-9  # 510 bytes after the first frame: 73 frames
    assert abs(transfer_budget(8192) - (1.0 + 0.01 * 1170)) < 1e-9


def record(directory, test, name, measured, most):
    directory.mkdir(parents=True, exist_ok=True)
    with open(directory / bounds.FILE, "a") as f:
        f.write(json.dumps({"test": test, "name": name, "measured": measured, "least": None,
                            "most": most, "unit": "s", "margin": most - measured,
                            "margin_of_limit": (most - measured) / most}) + "\n")


def test_the_smallest_margin_of_each_bound_over_runs(tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    record(one, "test_stop", "latency", 0.008, 0.015)
    record(one, "test_push", "arm", 0.1, 1.72)
    record(two, "test_stop", "latency", 0.013, 0.015)
    lines = bounds.smallest([one, two])
    assert len(lines) == 2
    stop = next(line for line in lines if line.startswith("test_stop"))
    assert "0.013 s" in stop and "margin 0.002 s" in stop and "of 2 run(s)" in stop and str(two) in stop
    assert "of 1 run(s)" in next(line for line in lines if line.startswith("test_push"))
    assert bounds.report(bounds.read(one))[0].startswith("run-hil: bound test_stop: latency: 0.008 s")
