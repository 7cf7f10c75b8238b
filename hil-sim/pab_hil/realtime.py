"""Real-time priority for what runs on a clock in the HIL suite: the nodes under test, their
drive, the world and the behaviours.

On a robot each of these has a computer of its own, or runs real-time on a shared one: a
camera's detector does not slow down when the arm's controller is busy, and a Linux node that
drives an arm is run under a real-time class. In the suite they share the machine (and, in the
micro-VM, two emulated CPUs) with the harness's Python, the recorder and the emulation, so each
asks the scheduler for SCHED_FIFO where it may (root: the micro-VM). Measured:

- the team world under two busy processes beside a software-emulated micro-VM: its worst
  lateness fell from 122-153 ms to 65 ms (`hil-sim/run-hil --hogs 2 -- -k multi_target`, figure
  `publisher_lag_s`);
- the Linux node's emergency stop at a 5 ms period, on a quiet machine: once 16.9 ms from the
  stop frame to the halted set-point at normal priority (its tick 11.6 ms late), which the
  suite's bound (a period and 10 ms) refused.

Where the class cannot be had (not root, not Linux), everything runs at normal priority, as
before, and the bounds' allowances are what absorb the scheduler (`pab_hil.speed`).
"""

from __future__ import annotations

import os

#: SCHED_FIFO's priority for the harness's loops: above every normal process, far below the
#: kernel's own threads (which run at 50).
PRIORITY = 10


def make_current_thread_realtime(priority: int = PRIORITY) -> bool:
    """Puts the calling thread in SCHED_FIFO at `priority`; False where that is not allowed (not
    root, no CAP_SYS_NICE, not Linux): the loop then runs at normal priority, as before."""
    try:
        # 0: the calling thread (on Linux the scheduling class is a thread's own).
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return True
    except (AttributeError, OSError):
        return False



def make_realtime(pid: int, priority: int = PRIORITY) -> bool:
    """Puts process `pid`'s main thread in SCHED_FIFO at `priority` (the threads it starts later
    inherit it), from its parent, just after it started (not from a `preexec_fn`, which is not
    safe in a parent with threads); False where that is not allowed."""
    try:
        os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(priority))
        return True
    except (AttributeError, OSError):
        return False
