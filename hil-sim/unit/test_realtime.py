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


def test_softirq_threads_run_ahead_of_the_loops_while_allowed_and_as_before_after():
    threads = realtime._softirq_threads()
    assert threads, "a Linux kernel runs one ksoftirqd thread per CPU"
    before = {pid: (os.sched_getscheduler(pid), os.sched_getparam(pid).sched_priority)
              for pid in threads}
    try:
        raised = realtime.keep_softirq_ahead()
        if raised:
            assert raised == len(threads)
            for pid in threads:
                assert os.sched_getscheduler(pid) == os.SCHED_FIFO
                assert os.sched_getparam(pid).sched_priority == realtime.SOFTIRQ_PRIORITY > realtime.PRIORITY
        else:  # not root: nothing changed
            assert {pid: (os.sched_getscheduler(pid), os.sched_getparam(pid).sched_priority)
                    for pid in threads} == before
    finally:
        realtime._restore_softirq()
    assert {pid: (os.sched_getscheduler(pid), os.sched_getparam(pid).sched_priority)
            for pid in threads} == before
