"""Real-time priority for the harness's world loops.

The world and the behaviours stand in for other computers: on a robot, a camera's detector does
not slow down when the arm's controller is busy. In the HIL suite they share the machine (and,
in the micro-VM, two emulated CPUs) with the nodes under test, so a loop that publishes on a
clock asks the scheduler for a real-time class (SCHED_FIFO) to keep that clock. Measured on the
team world under two busy processes beside a software-emulated micro-VM: its worst lateness fell
from 122-153 ms to 65 ms (`hil-sim/run-hil --hogs 2 -- -k multi_target`, figure
`publisher_lag_s`).
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
