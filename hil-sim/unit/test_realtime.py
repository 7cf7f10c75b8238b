"""pab_hil.realtime: a process asked to run real-time does so where the scheduler allows it, and
nothing fails where it does not."""

from __future__ import annotations

import os
import subprocess

from pab_hil import realtime


def test_a_child_runs_fifo_where_allowed_and_normal_otherwise():
    child = subprocess.Popen(["sleep", "5"])
    try:
        taken = realtime.make_realtime(child.pid)
        policy = os.sched_getscheduler(child.pid)
        if taken:
            assert policy == os.SCHED_FIFO
            assert os.sched_getparam(child.pid).sched_priority == realtime.PRIORITY
        else:
            assert policy == os.SCHED_OTHER
    finally:
        child.kill()
        child.wait()


def test_a_process_that_is_gone_is_no_error():
    child = subprocess.Popen(["true"])
    child.wait()
    assert realtime.make_realtime(child.pid) is False
