"""A flood of frames on one topic: what the arm node counts, delivers and re-publishes agree with
what the bus shows, and the figures for the README (how fast the node kept up)."""

from __future__ import annotations

import math
import shutil
import subprocess
import time

import pytest

from pab_hil import analysis, behaviours as b, world as w
from pab_hil.nodes import NODE_IDS
from pab_hil.person import TakeAndReturn

FLOOD = 5000
ARM = NODE_IDS["arm"]


@pytest.mark.parametrize("gap_ms", [1, 0], ids=["paced-1ms", "full-speed"])
def test_arm_node_counts_and_republishes_every_frame_of_a_flood(session_for, iface, figures, gap_ms):
    session = session_for(TakeAndReturn(show_at=math.inf), behaviours=())
    session.stream(0)  # only the flood and the heartbeats on the bus

    def counters():
        """The arm's counters from a heartbeat group that started after this call."""
        asked = session.world.now()
        session.wait_for(lambda: session.observer.node(ARM).heartbeat_time > asked + 0.05, 5,
                         "a fresh heartbeat group from the arm")
        time.sleep(0.1)  # Traffic follows the heartbeat at once
        return session.observer.node(ARM).traffic

    before = counters()
    cangen = shutil.which("cangen")
    assert cangen, "the flood needs cangen (can-utils: apt-get install can-utils)"
    # One frame per `gap_ms` (0: as fast as the socket takes them), waiting for room on ENOBUFS.
    flood_started = time.time()
    subprocess.run([cangen, iface, "-g", str(gap_ms), "-p", "10", "-I", f"{b.OBJECT_POS:X}", "-L", "8",
                    "-D", "i", "-n", str(FLOOD)], check=True, timeout=300)
    sent_in = time.time() - flood_started
    time.sleep(1.0)
    after = counters()
    session.close()

    messages = analysis.read_log(session.log_path)
    flood = [m for m in messages if m.arbitration_id == b.OBJECT_POS and not m.is_extended_id]
    republished = [m for m in messages if m.arbitration_id == w.ARM_TARGET_ID and not m.is_extended_id
                   and m.timestamp >= flood[0].timestamp]
    delivered = after.delivered - before.delivered
    received = after.received - before.received
    assert len(flood) == FLOOD  # the recorder saw the whole flood
    # Every delivery the node counted is on the bus, and nothing else was re-published: the
    # payloads are the flood's own.
    flood_payloads = {bytes(m.data) for m in flood}
    assert all(bytes(m.data) in flood_payloads for m in republished)
    assert delivered == len(republished), (delivered, len(republished))
    # The first frames only raise C1's stimulation to 1 (σ = 0.2: 5 frames), then every frame
    # the node received is delivered; a node that lost frames delivers fewer.
    assert 0 < delivered <= FLOOD - 4
    # cangen's payloads count up (-D i): the first one re-published says when C1 became active;
    # every flood frame from there on should have been delivered.
    first_delivered = next(i for i, m in enumerate(flood) if bytes(m.data) == bytes(republished[0].data))
    lost = FLOOD - first_delivered - delivered
    span = republished[-1].timestamp - flood[0].timestamp
    figures(f"flood-arm-node-{'paced-1ms' if gap_ms else 'full-speed'}", {
        "frames_sent": FLOOD,
        "offered_per_s": round(FLOOD / sent_in),
        "node_received_frames": received,
        "delivered": delivered,
        "lost": lost,
        "node_frames_per_s": round(received / span),
    })
