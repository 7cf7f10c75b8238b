"""Who drives a port is judged on bus time: a harness that reads the bus late (a loaded machine)
must not see gaps in a stream of deliveries that never stopped on the bus."""

from __future__ import annotations

import time

from pab_hil import world as w

PAYLOAD = bytes(8)


def world_at(seconds: float) -> w.World:
    world = w.World()
    world.epoch = time.time() - seconds  # the world began `seconds` ago
    return world


def test_a_delivery_is_fresh_while_the_harness_has_heard_less_than_fresh_seconds_after_it():
    world = world_at(10.0)
    # The harness is 7.8 s behind the bus: it just read a delivery stamped 2.0 s.
    world.on_delivery(w.ARM_TARGET_ID, PAYLOAD, world.epoch + 2.0)
    assert world.heard_until() == 2.0
    assert world.last_delivery("arm", within=0.5) is not None  # on the wall clock: 8 s old
    world.on_bus_time(world.epoch + 2.4)  # a heartbeat, 0.4 s later on the bus
    assert world.last_delivery("arm", within=0.5) is not None
    world.on_bus_time(world.epoch + 2.6)  # 0.6 s of bus without another delivery
    assert world.last_delivery("arm", within=0.5) is None


def test_a_harness_that_keeps_up_judges_on_the_wall_clock():
    world = world_at(10.0)
    world.on_delivery(w.ARM_TARGET_ID, PAYLOAD, world.epoch + 9.8)
    world.on_bus_time(world.epoch + 30.0)  # a timestamp ahead of the wall clock is capped
    assert 9.99 < world.heard_until() < 10.5
    assert world.last_delivery("arm", within=0.5) is not None
    assert world.last_delivery("arm", within=0.1) is None


def test_nothing_delivered_is_nobody():
    world = world_at(1.0)
    world.on_bus_time(world.epoch + 0.9)
    assert world.last_delivery("arm", within=0.5) is None
    assert world.last_delivery("gaze", within=0.5) is None
