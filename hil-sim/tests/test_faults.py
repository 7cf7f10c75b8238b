"""A behaviour process dies: its connections decay and the next rule takes over, in the decay
time the network file gives them, and not before."""

from __future__ import annotations

import tomllib

from pab_hil import analysis, behaviours as b
from pab_hil.nodes import NODE_IDS, TAKE_AND_RETURN
from pab_hil.person import TakeAndReturn
from pab_hil.phases import driver

# s: scheduling slack on top of the exact figures, on the reference machine (scaled by
# `machine.allow`): the nodes, the behaviours and the observer are processes on a possibly
# emulated machine.
SLACK = 0.8
# s: how far a node's clock (it stamps a frame when it reads it) may run behind the bus's
# timestamps, on the reference machine.
CLOCKS = 0.1


def test_killed_object_detector_decays_and_rest_arm_and_look_around_take_over(session_for, bound,
                                                                             machine):
    network = tomllib.loads(TAKE_AND_RETURN.read_text())
    decay = network["connections"]["C1"]["tc"]  # object_pos -> arm.target
    assert network["connections"]["C3"]["tc"] == decay  # object_pos -> gaze.target
    rest_period = 1 / b.BEHAVIOURS["rest-arm"].rate_hz
    look_period = 1 / b.BEHAVIOURS["look-around"].rate_hz

    session = session_for(TakeAndReturn())
    session.wait_for(lambda: driver(session.world, "arm") == "object-detector", 60,
                     "the arm reaching (driven by Object Detector)")
    session.behaviours.kill("object-detector")
    killed_at = session.world.now()
    session.wait_for(lambda: driver(session.world, "arm") == "rest-arm", decay + 10,
                     "Rest Arm taking the arm over")
    session.wait_for(lambda: driver(session.world, "gaze", within=1.5) == "look-around", 10,
                     "Look Around taking the gaze over")
    session.close()

    # From the bus log (kernel timestamps): the last object_pos frame, and the first frames each
    # node then re-published from Rest Arm and Look Around.
    messages = analysis.read_log(session.log_path)
    last_object = max(m.timestamp for m in messages if m.arbitration_id == b.OBJECT_POS)
    bound("the last object frame after the kill", last_object - session.world.epoch - killed_at,
          most=machine.allow(0.05))

    def first_after(gateway: int, topic: int, origin: str) -> float:
        """The first re-publication of a frame the behaviour published after the last object
        frame. Matched by payload (each carries its tick): a frame published before it but
        re-published after (the two crossing in a node's socket) does not count."""
        origin_id = b.BEHAVIOURS[origin].origin
        published = {bytes(m.data) for m in messages
                     if m.arbitration_id == topic and not m.is_extended_id
                     and m.timestamp > last_object}
        return min(m.timestamp for m in messages
                   if m.arbitration_id == gateway and m.timestamp > last_object
                   and not m.is_extended_id and m.data[7] == origin_id
                   and bytes(m.data) in published)

    arm_takeover = first_after(0x200, b.REST_POSE, "rest-arm") - last_object
    gaze_takeover = first_after(0x201, b.LOOK_TARGET, "look-around") - last_object
    # Not before the decay time: C1 and C3 stay active, and inhibit C14 and C11, for `decay` s.
    early = decay - machine.allow(CLOCKS)
    bound("Rest Arm's takeover", arm_takeover, least=early,
          most=decay + rest_period + machine.allow(SLACK))
    bound("Look Around's takeover", gaze_takeover, least=early,
          most=decay + look_period + machine.allow(SLACK))

    # The nodes' own view: C1 (arm port 0, connection 0) went inactive with S decayed to 0.
    arm_samples = [s for s in session.samples(NODE_IDS["arm"])
                   if s.sample.port == 0 and s.sample.connection == 0]
    after = [s for s in arm_samples if s.time > last_object - session.world.epoch]
    # The first rounds may predate the node's handling of the last frame (kernel timestamps).
    active = [i for i, s in enumerate(after) if s.sample.active]
    assert active, "C1 should still be active just after the kill"
    inactive = [s for s in after[active[0]:] if not s.sample.active]
    assert inactive, "C1 never became inactive in the arm node's diagnostic stream"
    assert inactive[0].sample.level == 0.0
    became_inactive = inactive[0].time - (last_object - session.world.epoch)
    bound("C1 inactive in the arm's stream", became_inactive, least=early,
          most=decay + machine.allow(SLACK))
