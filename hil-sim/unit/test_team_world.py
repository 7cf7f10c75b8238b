"""The multi-target observation world on its own: geometry, the frames behaviours publish, and
the robot's motion. The HIL suite then runs it against the nodes."""

from __future__ import annotations

import math

import pytest

from pab_hil import team as t


def test_a_robot_sees_what_is_in_its_cone_and_range_only():
    pose = t.Pose(1000.0, 1000.0, 0.0)
    assert t.sees(pose, (2000.0, 1000.0))
    assert t.sees(pose, (2000.0, 1000.0 + 1000.0 * math.tan(math.radians(29.0))))
    assert not t.sees(pose, (2000.0, 1000.0 + 1000.0 * math.tan(math.radians(31.0))))
    assert not t.sees(pose, (1000.0 + t.CAMERA_RANGE + 1, 1000.0))
    assert not t.sees(pose, (0.0, 1000.0))  # behind


def test_bearing_wraps_to_a_half_turn_either_side():
    pose = t.Pose(0.0, 0.0, 350.0)
    assert t.bearing(pose, (1.0, 0.0)) == pytest.approx(10.0)
    assert t.bearing(t.Pose(0.0, 0.0, 10.0), (1.0, 0.0)) == pytest.approx(-10.0)
    assert -180.0 <= t.bearing(pose, (-1.0, 0.0)) < 180.0


def test_eligibility_is_higher_when_closer_and_zero_out_of_view():
    pose = t.Pose(0.0, 0.0, 0.0)
    near, far = t.eligibility(pose, (500.0, 0.0)), t.eligibility(pose, (2000.0, 0.0))
    assert 1000 > near > far >= 1
    assert t.eligibility(pose, (-500.0, 0.0)) == 0


def test_a_command_round_trips_and_carries_its_eligibility_where_the_ble_field_says():
    command = t.Command(-12.34, 777, 3, 2, 300, 42)
    payload = command.encode()
    assert len(payload) == 8
    decoded = t.Command.decode(payload)
    assert decoded == t.Command(-12.34, 777, 3, 2, 300 & 0xFF, 42)
    assert int.from_bytes(payload[t.ELIGIBILITY_OFFSET:t.ELIGIBILITY_OFFSET + 2], "little") == 777
    assert t.Command.decode(payload[:7]) is None


def test_an_observer_turns_towards_its_target_and_is_silent_without_it():
    target = t.Target(1, (3000.0, 3000.0), 1.0, 0.0)
    left = t.observer_command(t.Pose(2000.0, 2900.0, 0.0), target, 0.0, 1, 0, 9)
    assert left is not None and left.rotate > 0 and left.eligibility > 0 and left.target == 1
    assert t.observer_command(t.Pose(2000.0, 2900.0, 180.0), target, 0.0, 1, 0, 9) is None


def test_robots_stay_in_the_arena_and_turn_as_commanded():
    pose = t.Pose(100.0, 3000.0, 180.0)  # heading into the west wall
    for _ in range(100):
        pose = t.step(pose, 0.0, 0.05)
        assert 0.0 <= pose.x <= t.ARENA and 0.0 <= pose.y <= t.ARENA
    # It bounced: now heading east, away from the wall it reached.
    assert pose.heading == pytest.approx(0.0) and pose.x > 100.0
    turned = t.step(t.Pose(3000.0, 3000.0, 0.0), 45.0, 1.0)
    assert turned.heading == pytest.approx(45.0)
    clamped = t.step(t.Pose(3000.0, 3000.0, 0.0), 1000.0, 1.0)
    assert clamped.heading == pytest.approx(t.MAX_TURN)


def test_targets_orbit_at_their_speed_and_wander_is_reproducible():
    target = t.default_targets()[0]
    a, b = target.at(0.0), target.at(1.0)
    assert math.dist(a, b) == pytest.approx(t.TARGET_SPEED, rel=0.01)
    one, two = t.Wander(7), t.Wander(7)
    assert [one.command(s / 10, 1, 0, 0).rotate for s in range(30)] == \
        [two.command(s / 10, 1, 0, 0).rotate for s in range(30)]
