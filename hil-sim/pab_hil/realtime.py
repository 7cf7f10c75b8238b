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

Once anything runs real-time, the kernel's softirq threads (`ksoftirqd/N`) must run ahead of it:
on vcan every frame written reaches the other sockets through the writing CPU's receive backlog,
which a softirq empties, and a kernel without PREEMPT_RT leaves that work to `ksoftirqd` at normal
priority once it has run long. A node re-publishing a flood at SCHED_FIFO then kept `ksoftirqd` off
its CPU, the backlog (`netdev_max_backlog`, 1 000 frames) overflowed and the kernel dropped frames
the node had written, without an error to the node: 926 in one run of the flood tests beside two
busy processes (`/proc/net/softnet_stat`, which those tests now read), the re-publications
missing from the log. A robot's Linux controller that runs `pab-node`
real-time needs the same (`chrt -f -p 11 $(pgrep ksoftirqd)`), or it loses the echo of its own
frames to local listeners (on vcan: the bus).
"""

from __future__ import annotations

import atexit
import os

#: SCHED_FIFO's priority for the harness's loops: above every normal process, far below the
#: kernel's own threads (which run at 50).
PRIORITY = 10

#: SCHED_FIFO's priority for the kernel's softirq threads while the suite runs loops real-time:
#: just above them.
SOFTIRQ_PRIORITY = PRIORITY + 1


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


_softirq_restore: dict[int, tuple[int, int]] = {}


def keep_softirq_ahead(priority: int = SOFTIRQ_PRIORITY) -> int:
    """Puts every `ksoftirqd/N` thread in SCHED_FIFO at `priority`, once per process, and puts
    them back as they were when the process exits (on a developer's machine with vcan0, as root,
    the suite leaves the kernel as it found it). Returns how many threads run at `priority`; 0
    where that is not allowed."""
    if not _softirq_restore:
        for pid in _softirq_threads():
            try:
                policy = os.sched_getscheduler(pid)
                previous = os.sched_getparam(pid).sched_priority
                os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(priority))
            except (AttributeError, OSError):
                continue
            _softirq_restore[pid] = (policy, previous)
        if _softirq_restore:
            atexit.register(_restore_softirq)
    return len(_softirq_restore)


def _softirq_threads() -> list[int]:
    threads = []
    for entry in os.scandir("/proc") if os.path.isdir("/proc") else ():
        if not entry.name.isdigit():
            continue
        try:
            with open(f"/proc/{entry.name}/comm") as comm:
                if comm.read().startswith("ksoftirqd/"):
                    threads.append(int(entry.name))
        except OSError:
            continue  # gone meanwhile
    return threads


def _restore_softirq() -> None:
    for pid, (policy, priority) in _softirq_restore.items():
        try:
            os.sched_setscheduler(pid, policy, os.sched_param(priority))
        except OSError:
            pass  # nothing left to restore
    _softirq_restore.clear()
