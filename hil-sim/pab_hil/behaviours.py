"""The seven behaviours of Figure 4 of the iCub paper, each a publisher with its own preconditions.

A behaviour knows nothing of the others nor of the arbitration: at its rate it looks at the world
(its sensors), and if its local precondition holds it publishes its frames on its topics, exactly
as it would on the robot. Each runs in its own process (forked from the harness, so that it starts
at once and can be killed like any process) with its own CAN socket.
"""

from __future__ import annotations

import multiprocessing
import os
import random
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass

import can

from . import world as w
from .realtime import make_current_thread_realtime

# The topics' CAN ids: the publishers' own, unchanged (see examples/take-and-return.toml).
OBJECT_POS = 0x110
FACE_POS = 0x111
LOOK_TARGET = 0x112
REST_POSE = 0x113
GRASP_CMD = 0x120
RELEASE_CMD = 0x121
REST_OPEN = 0x122
GRASPED = 0x130

Frames = list[tuple[int, bytes]]


@dataclass(frozen=True)
class Behaviour:
    name: str
    origin: int  # byte 7 of its frames
    rate_hz: float
    topics: tuple[int, ...]
    publish: Callable[[w.Snapshot, int, int], Frames]  # (snapshot, tick, origin) -> frames


def _object_detector(s: w.Snapshot, tick: int, origin: int) -> Frames:
    # Sees an object held out to it, in view; not one in the robot's own hand (which hides it).
    if s.holder == w.PERSON_SHOWS and s.in_view(s.object):
        return [(OBJECT_POS, w.encode_position(s.object, tick, origin))]
    return []


def _face_detector(s: w.Snapshot, tick: int, origin: int) -> Frames:
    if s.face_present and s.in_view(w.FACE_AT):
        return [(FACE_POS, w.encode_position(w.FACE_AT, tick, origin))]
    return []


def _look_around(s: w.Snapshot, tick: int, origin: int) -> Frames:
    target = w.LOOK_AROUND_TARGETS[tick % len(w.LOOK_AROUND_TARGETS)]
    return [(LOOK_TARGET, w.encode_position(target, tick, origin))]


def _rest_arm(s: w.Snapshot, tick: int, origin: int) -> Frames:
    # Silent while the hand holds the object: resting would drop it.
    if s.holder == w.HAND:
        return []
    return [
        (REST_POSE, w.encode_position(w.REST_POSE, tick, origin)),
        (REST_OPEN, w.encode_command(w.OPEN, tick, origin)),
    ]


def _grasp_detect(s: w.Snapshot, tick: int, origin: int) -> Frames:
    if (
        s.holder == w.PERSON_SHOWS
        and s.hand_open
        and w.distance(s.hand, s.object) <= w.GRASP_REACH
    ):
        return [(GRASP_CMD, w.encode_command(w.CLOSE, tick, origin))]
    return []


def _release_detect(s: w.Snapshot, tick: int, origin: int) -> Frames:
    if s.holder == w.HAND and s.face_present and w.distance(s.hand, w.FACE_AT) <= w.RELEASE_REACH:
        return [(RELEASE_CMD, w.encode_command(w.OPEN, tick, origin))]
    return []


def _grasped(s: w.Snapshot, tick: int, origin: int) -> Frames:
    # Touch sensors and finger encoders: the hand is closed on the object.
    if s.holder == w.HAND and s.hand_closed:
        return [(GRASPED, w.encode_command(1, tick, origin))]
    return []


BEHAVIOURS: dict[str, Behaviour] = {
    b.name: b
    for b in (
        Behaviour("object-detector", 1, 10.0, (OBJECT_POS,), _object_detector),
        Behaviour("face-detector", 2, 10.0, (FACE_POS,), _face_detector),
        Behaviour("grasp-detect", 3, 10.0, (GRASP_CMD,), _grasp_detect),
        Behaviour("release-detect", 4, 10.0, (RELEASE_CMD,), _release_detect),
        Behaviour("grasped", 5, 10.0, (GRASPED,), _grasped),
        Behaviour("look-around", 6, 1.0, (LOOK_TARGET,), _look_around),
        Behaviour("rest-arm", 7, 5.0, (REST_POSE, REST_OPEN), _rest_arm),
    )
}
BY_ORIGIN = {b.origin: b.name for b in BEHAVIOURS.values()}


@dataclass(frozen=True)
class Loss:
    """Frames a behaviour drops instead of sending, as a lossy link would: each frame with
    probability `rate`, decided by a generator seeded with `seed` and the behaviour's name (the
    same seed drops the same frames of each behaviour's sequence)."""

    rate: float
    seed: int


def publish_forever(behaviour: Behaviour, world: w.World, iface: str, loss: Loss | None = None,
                    counts=None, paused=None) -> None:
    """The body of a behaviour process: publish at the behaviour's rate until killed. With `loss`,
    drop frames at random and count them in `counts` (a shared array: frames sent, dropped); while
    `paused` (an event) is set, publish nothing."""
    signal.signal(signal.SIGTERM, lambda *_: os._exit(0))
    # Another computer's sensor pipeline: its clock does not wait for the nodes (pab_hil.realtime).
    make_current_thread_realtime()
    bus = can.Bus(interface="socketcan", channel=iface)
    rng = random.Random(f"{loss.seed}:{behaviour.name}") if loss else None
    period = 1.0 / behaviour.rate_hz
    deadline = time.monotonic()
    tick = 0
    while True:
        frames = [] if paused is not None and paused.is_set() else \
            behaviour.publish(world.snapshot(), tick, behaviour.origin)
        for can_id, payload in frames:
            if rng is not None and rng.random() < loss.rate:
                if counts is not None:
                    counts[1] += 1
                continue
            bus.send(can.Message(arbitration_id=can_id, is_extended_id=False, data=payload))
            if counts is not None:
                counts[0] += 1
        tick += 1
        deadline += period
        delay = deadline - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:  # late (a loaded machine): keep the rate from now on rather than burst
            deadline = time.monotonic()


class BehaviourProcesses:
    """The behaviours as forked processes, by name; with `loss`, each drops frames at random."""

    def __init__(self, world: w.World, iface: str, names=None, loss: Loss | None = None) -> None:
        context = multiprocessing.get_context("fork")
        self.loss = loss
        self._paused = context.Event()
        self.processes: dict[str, multiprocessing.Process] = {}
        # Per behaviour: frames sent, frames dropped (written by its process only).
        self._counts = {name: multiprocessing.RawArray("q", 2)
                        for name in (BEHAVIOURS if names is None else names)}
        for name in BEHAVIOURS if names is None else names:
            process = context.Process(
                target=publish_forever,
                args=(BEHAVIOURS[name], world, iface, loss, self._counts[name], self._paused),
                name=name,
                daemon=True,
            )
            self.processes[name] = process

    def pause(self) -> None:
        """Every behaviour stops publishing (at its next tick) until `resume`."""
        self._paused.set()

    def resume(self) -> None:
        self._paused.clear()

    def counts(self) -> dict[str, tuple[int, int]]:
        """Per behaviour: (frames sent, frames dropped) so far."""
        return {name: (counts[0], counts[1]) for name, counts in self._counts.items()}

    def start(self) -> None:
        for process in self.processes.values():
            process.start()

    def kill(self, name: str) -> None:
        """SIGKILL: the behaviour stops mid-stride, as a crashed process would."""
        process = self.processes[name]
        process.kill()
        process.join(timeout=5)

    def alive(self, name: str) -> bool:
        return self.processes[name].is_alive()

    def stop(self) -> None:
        for process in self.processes.values():
            if process.is_alive():
                process.terminate()
        for process in self.processes.values():
            process.join(timeout=5)
