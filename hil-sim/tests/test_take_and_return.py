"""The paper's Take and Return in closed loop, and its variant where the person takes the object
back during the approach."""

from __future__ import annotations

from pab_hil import analysis, behaviours as b, world as w
from pab_hil.person import TakeAndReturn
from pab_hil.phases import driver


def test_phases_a_to_f_end_with_the_object_handed_to_the_person(session_for, out_dir, figures):
    person = TakeAndReturn()
    session = session_for(person)
    session.wait_for(lambda: person.handed_over_at is not None, 60, "the handover")
    session.wait_for(
        lambda: session.phases.current() == "A" and not session.world.snapshot().face_present,
        30,
        "back to A after the handover",
    )
    assert session.phases.sequence() == list("ABCDEFA"), session.phase_report()
    session.wait_for(
        lambda: w.distance(session.world.snapshot().hand, w.REST_POSE) < 1.0, 10, "the arm at rest"
    )
    end = session.world.snapshot()
    assert end.holder == w.PERSON_KEEPS, session.phase_report()
    assert end.hand_open
    session.close()
    from pab_hil.plot import plot_session  # matplotlib: imported only when a test draws

    plot_session(session, out_dir / "take-and-return.png", title="take and return, closed loop")

    # What the bus shows: every frame the arm node re-published carries a payload some behaviour
    # published before it (the gateway invents nothing), and the figures for the README.
    messages = analysis.read_log(session.log_path)
    arm_topics = {b.OBJECT_POS, b.FACE_POS, b.REST_POSE, b.GRASP_CMD, b.RELEASE_CMD, b.GRASPED}
    latency = analysis.gateway_latency(messages, arm_topics, w.ARM_TARGET_ID)
    assert latency.count > 20 and latency.unmatched == 0, latency
    duration = messages[-1].timestamp - messages[0].timestamp
    figures("latency-behaviour-to-arm", {
        "deliveries": latency.count,
        "median_ms": round(latency.median_ms, 3),
        "p99_ms": round(latency.p99_ms, 3),
        "max_ms": round(latency.max_ms, 3),
    })
    figures("take-and-return-bus", {
        "frames": len(messages),
        "seconds": round(duration, 1),
        "frames_per_s": round(len(messages) / duration),
    })


def test_person_takes_the_object_back_during_the_approach_and_the_system_returns_to_a(session_for):
    person = TakeAndReturn(takes_back=True)
    session = session_for(person)
    session.wait_for(lambda: person.took_back_at is not None, 60, "the person taking the object back")
    # Back to A on its own: Rest Arm drives the arm and opens the hand, Look Around the gaze.
    session.wait_for(
        lambda: session.phases.current() == "A"
        and driver(session.world, "hand") == "rest-arm"
        and driver(session.world, "gaze", within=1.5) == "look-around",
        30,
        "back to A after the take-back",
    )
    assert session.phases.sequence() == list("ABCDEA"), session.phase_report()
    session.wait_for(lambda: session.world.snapshot().hand_open, 5, "the hand open again")
    assert session.world.snapshot().holder == w.PERSON_KEEPS
