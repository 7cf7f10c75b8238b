"""A flood of frames on one topic: the arm node accounts for every frame (read, or counted as lost
by the kernel), re-publishes exactly what it counts as delivered, and the figures for the book
(how fast the node kept up, and how much it lost)."""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from pab_hil import analysis, behaviours as b, observe, protocol as p, world as w
from pab_hil.nodes import NODE_IDS
from pab_hil.person import TakeAndReturn

FLOOD = 5000
ARM = NODE_IDS["arm"]
# Sent after the flood has drained: the kernel reports the frames it dropped with the next frame
# the node reads, and the flood's last losses need one. No table uses this identifier.
SENTINEL = 0x7F0
# Frames each CPU's receive backlog holds (the kernel's default, and the micro-VM's).
BACKLOG = int(Path("/proc/sys/net/core/netdev_max_backlog").read_text()) \
    if Path("/proc/sys/net/core/netdev_max_backlog").exists() else 1000
SMALL_BUFFER = 16384  # bytes: 22 frames at 768 bytes each
TRUESIZE = 768  # what the kernel charges per queued CAN frame (python -m pab_hil.truesize)


def counters(session):
    """The arm's (Traffic, Errors) from a heartbeat group that started after this call."""
    asked = session.world.now()
    session.wait_for(lambda: session.observer.node(ARM).heartbeat_time > asked + 0.05, 5,
                     "a fresh heartbeat group from the arm")
    time.sleep(0.15)  # Traffic and Errors follow the heartbeat at once; a pending fault within 100 ms
    view = session.observer.node(ARM)
    return view.traffic, view.errors


def frames_lost(messages, before=None):
    """The arm's frames lost since boot, from the latest RxOverrun fault in the log (sent before
    `before`, a kernel timestamp, if given); 0 if none."""
    overruns = [f for at, f in analysis.faults(messages, ARM)
                if f.code == p.RX_OVERRUN and (before is None or at < before)]
    return overruns[-1].frames_lost if overruns else 0


@pytest.mark.parametrize("gap_ms, rcvbuf", [(1, None), (0, None), (0, SMALL_BUFFER)],
                         ids=["paced-1ms", "full-speed", f"full-speed-{SMALL_BUFFER}-byte-buffer"])
def test_arm_node_accounts_for_every_frame_of_a_flood(session_for, iface, out_dir, figures, bound,
                                                      gap_ms, rcvbuf):
    node_args = {"arm": ("--rcvbuf", str(rcvbuf))} if rcvbuf else None
    session = session_for(TakeAndReturn(show_at=math.inf), behaviours=(), node_args=node_args)
    session.stream(0)
    # The arm node alone with the flood: the other nodes' heartbeats would reach it too, and
    # then the frames it should read could not be told from the log.
    session.nodes["hand"].stop()
    session.nodes["gaze"].stop()
    time.sleep(0.3)  # their last frames read

    before_traffic, before_errors = counters(session)
    backlog_drops_before = observe.backlog_drops()
    cangen = shutil.which("cangen")
    assert cangen, "the flood needs cangen (can-utils: apt-get install can-utils)"
    # One frame per `gap_ms` (0: as fast as the socket takes them), waiting for room on ENOBUFS.
    flood_started = time.time()
    subprocess.run([cangen, iface, "-g", str(gap_ms), "-p", "10", "-I", f"{b.OBJECT_POS:X}", "-L", "8",
                    "-D", "i", "-n", str(FLOOD)], check=True, timeout=300)
    sent_in = time.time() - flood_started
    # The node has read all it will read of the flood when two heartbeat groups agree.
    received_then = None
    for _ in range(60):
        traffic, _ = counters(session)
        if traffic.received == received_then:
            break
        received_then = traffic.received
    else:
        pytest.fail("the arm node was still reading the flood after 60 heartbeat groups")
    session.listening.send(SENTINEL, b"", extended=False)
    after_traffic, after_errors = counters(session)
    backlog_drops = (observe.backlog_drops() or 0) - (backlog_drops_before or 0)
    session.close()

    messages = analysis.read_log(session.log_path)
    flood = [m for m in messages if m.arbitration_id == b.OBJECT_POS and not m.is_extended_id]
    republished = [m for m in messages if m.arbitration_id == w.ARM_TARGET_ID and not m.is_extended_id
                   and m.timestamp >= flood[0].timestamp]
    received = after_traffic.received - before_traffic.received
    delivered = after_traffic.delivered - before_traffic.delivered
    # Frames lost, from the log: the fault that reports them goes out while the flood's
    # re-publications still fill the bus.
    lost = frames_lost(messages) - frames_lost(messages, before=flood[0].timestamp)
    errors = after_errors.errors - before_errors.errors
    assert len(flood) == FLOOD  # the recorder saw the whole flood
    # Every frame sent to the node was read or counted as lost by the kernel, nothing twice.
    sent = FLOOD + 1  # and the sentinel
    assert received + lost == sent, dict(received=received, lost=lost, sent=sent)
    # Each frame lost is one error (nothing else went wrong: a failed re-publication would raise
    # TxOverrun, which counts one error too).
    tx_overruns = [f for _, f in analysis.faults(messages, ARM) if f.code == 0x0012]
    assert errors == lost or (tx_overruns and errors > lost), (errors, lost, tx_overruns)
    # Every delivery the node counted is on the bus, and nothing else was re-published: the
    # payloads are the flood's own.
    index = {bytes(m.data): i for i, m in enumerate(flood)}
    assert all(bytes(m.data) in index for m in republished)
    # A re-publication the kernel dropped on its way to the other sockets is lost on the bus
    # (vcan) with no error to the node: the softirq that carries frames to sockets was kept from
    # running (pab_hil.realtime).
    assert backlog_drops == 0, f"the kernel dropped {backlog_drops} frames from its receive backlogs"
    assert delivered == len(republished), (delivered, len(republished))
    # No flood frame is re-published twice, and every flood frame missing from the
    # re-publications between the first and the last was counted as lost (C1 stays active
    # through the flood once 5 frames have raised it: σ = 0.2). (Not their order: the kernel
    # queues a process's frames on the CPU it runs on, so a recorder on another socket may see
    # two of them swapped.)
    order = sorted(index[bytes(m.data)] for m in republished)
    assert len(set(order)) == len(order)
    missing = (order[-1] - order[0] + 1) - delivered
    assert 0 < delivered and missing <= lost, (delivered, missing, lost)
    # Why frames were lost, measured: the receive queue was full. Its capacity in frames is the
    # buffer the node got (its log) over what the kernel charges per frame; when the first frame
    # was dropped, the frames sent and not yet read by the node (whose progress is its
    # re-publications: it re-publishes a frame before it reads the next) must be that many.
    got = int(re.search(r"receive buffer (\d+) bytes",
                        (out_dir / "logs" / "arm.log").read_text()).group(1))
    capacity = math.ceil(got / TRUESIZE)
    queued_at_first_loss = None
    if lost:
        # The first loss after the node's first re-publication (earlier ones, while C1 was
        # becoming active, do not show the node's progress).
        present = set(order)
        first_lost, read_up_to = next(
            (i, max(index[bytes(m.data)] for m in republished if m.timestamp <= flood[i].timestamp))
            for i in range(order[0] + 1, FLOOD)
            if i not in present and republished[0].timestamp <= flood[i].timestamp)
        queued_at_first_loss = first_lost - 1 - read_up_to
        # The kernel drops a frame only when the queue holds `capacity` frames. What is measured
        # here can only be more: a frame is timestamped when it is sent, into the sending CPU's
        # backlog, and queued (or dropped) when the kernel's softirq gets to it; the frames ahead
        # of it in the backlogs reach the node first, and it may read them meanwhile. And the
        # node may have read a frame it has not re-published yet. So: at least the capacity, and
        # more by at most what the backlogs hold and one. Not a time: how far the softirq
        # trails the sender is the emulated machine's scheduling (in quiet fresh-clone runs, 7
        # frames over a capacity of 22 at 2 600 frames/s and 315 at 13 900 frames/s; 201 at
        # 3 400 frames/s beside two busy processes).
        backlogs = BACKLOG * (os.cpu_count() or 1)
        bound("frames waiting when the first was dropped", queued_at_first_loss, unit="frames",
              least=capacity - 1, most=capacity + backlogs + 1,
              detail=f"frame {first_lost}; the queue holds {capacity}, the backlogs {backlogs}")
    offered = FLOOD / sent_in
    span = republished[-1].timestamp - flood[0].timestamp
    node_rate = (received - 1) / span
    if rcvbuf is None and gap_ms == 0 and lost:
        # The default buffer holds 100 ms of a saturated 1 Mbit/s bus (2 128 frames): frames are
        # lost only once the backlog reaches it, which the check of the queue at the first loss
        # above asserts. Not the average rates: a node that reads faster on average still loses
        # frames when the emulated machine stalls it longer than the queue lasts (a fresh run:
        # offered 25 400 frames/s, read 28 200/s over the flood, frames lost with the queue full).
        print(f"full speed: {lost} of {FLOOD} frames lost: offered {offered:.0f} frames/s, the "
              f"node read {node_rate:.0f} frames/s, the queue was full ({queued_at_first_loss} "
              f"frames, capacity {capacity}) when frame {first_lost} came")
    elif rcvbuf is None:
        assert lost == 0, f"{lost} of {FLOOD} frames lost at one frame per {gap_ms} ms"
    else:
        assert lost > 0, f"a {rcvbuf}-byte buffer should overflow at full speed"
    name = f"flood-arm-node-{'paced-1ms' if gap_ms else 'full-speed'}"
    figures(name + (f"-rcvbuf-{rcvbuf}" if rcvbuf else ""), {
        "frames_sent": FLOOD,
        "offered_per_s": round(offered),
        "node_read": received - 1,
        "delivered": delivered,
        "lost_counted": lost,
        "node_frames_per_s": round(node_rate),
        "queue_capacity_frames": capacity,
        "queued_at_first_loss": queued_at_first_loss,
    })
