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


def _message(at, robot, target):
    import can
    command = t.Command(0.0, 0, target, robot, 0, 0)
    return can.Message(timestamp=at, arbitration_id=t.drive_id(robot), is_extended_id=False,
                       data=command.encode())


def test_drives_hold_until_the_next_command_or_the_rotate_timeout():
    messages = [_message(0.00, 1, 2), _message(0.05, 1, 2), _message(0.10, 1, 0),
                _message(1.00, 1, 2)]
    assert t.drives(messages) == [
        t.Drive(1, 2, 0.00, 0.10),
        t.Drive(1, 0, 0.10, 0.10 + t.ROTATE_TIMEOUT),
        t.Drive(1, 2, 1.00, 1.00 + t.ROTATE_TIMEOUT),
    ]


def test_shared_driving_and_coverage_are_read_from_the_drives():
    drives = [t.Drive(1, 2, 0.0, 1.0), t.Drive(2, 2, 0.9, 2.0), t.Drive(3, 1, 0.0, 0.5),
              t.Drive(3, 2, 3.0, 3.5)]
    [(a, b, robots)] = t.shared(drives, 2)
    assert (a, b, robots) == (0.9, 1.0, (1, 2))
    assert t.shared(drives, 1) == []
    assert t.coverage(drives, 2, 0.0, 4.0) == pytest.approx(2.5 / 4.0)
    assert t.coverage(drives, 1, 0.0, 4.0) == pytest.approx(0.5 / 4.0)
    assert t.coverage(drives, 4, 0.0, 4.0) == 0.0


def test_a_placed_scene_stands_still_and_its_observers_publish_equal_eligibilities():
    world = t.TeamWorld({1: t.Pose(2000.0, 3000.0, 0.0), 2: t.Pose(4000.0, 3000.0, 180.0)})
    world.place({}, tuple(t.Target(n, (3000.0, 3000.0) if n == 2 else (100.0 * n, 5900.0),
                                   0.0, 0.0, speed=0.0) for n in t.TARGETS))
    world.step(1.0)
    assert world.poses[1] == t.Pose(2000.0, 3000.0, 0.0)
    assert world.eligibilities()[(1, 2)] == world.eligibilities()[(2, 2)] > 0
    frames = dict(world.frames())
    assert set(frames) == {t.observer_id(1, 2), t.observer_id(2, 2), t.wander_id(1),
                           t.wander_id(2)}
    assert t.Command.decode(frames[t.observer_id(1, 2)]).target == 2


def test_the_board_routes_are_disjoint_and_cover_its_topics_and_claims():
    def passes(route, can_id):
        ident, mask = (int(x, 16) for x in route.split(":"))
        return can_id & mask == ident & mask
    routes = t.board_routes(3)
    eff = 0x8000_0000
    wanted = [t.observer_id(3, n) for n in t.TARGETS] + [t.wander_id(3), eff | 0x1280_0083]
    for can_id in wanted:
        assert sum(passes(r, can_id) for r in routes) == 1, hex(can_id)
    for can_id in [t.observer_id(1, 1), t.wander_id(2), t.drive_id(3)]:
        assert not any(passes(r, can_id) for r in routes), hex(can_id)
