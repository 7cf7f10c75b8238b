"""The phases of Take and Return (A to F), read from what the world shows.

A phase is recognised from the robot's state and from who drives each port, as the world received
it from the nodes (the publisher's id travels in every payload). It is an observation of the
system's behaviour, not a prediction: nothing here knows the rules.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from . import behaviours as b
from . import world as w

# A port is "driven by" a behaviour while its deliveries keep coming: 5 periods at 10 Hz, in bus
# time (World.last_delivery): a harness that reads the bus late must not see gaps the bus never
# had.
FRESH = 0.5

NAMES = {
    "A": "looking for an object",
    "B": "reaching for the object",
    "C": "grasping",
    "D": "looking for a person while holding the object",
    "E": "approaching the person",
    "F": "releasing the object",
    "-": "in between",
}


def driver(world: w.World, port: str, within: float = FRESH) -> str | None:
    """The behaviour whose frames the port delivered last, if less than `within` ago."""
    delivery = world.last_delivery(port, within)
    return None if delivery is None else b.BY_ORIGIN.get(delivery.origin, f"origin {delivery.origin}")


def classify(world: w.World) -> str:
    s = world.snapshot()
    arm, hand = driver(world, "arm"), driver(world, "hand")
    if hand == "release-detect":
        return "F"
    if s.holder == w.HAND and arm == "face-detector":
        return "E"
    if hand == "grasp-detect":
        return "C"
    if s.holder != w.HAND and arm == "object-detector":
        return "B"
    if s.holder == w.HAND:
        return "D"
    if arm == "rest-arm":
        return "A"
    return "-"


@dataclass(frozen=True)
class Change:
    time: float
    phase: str


class PhaseLog:
    """Phase changes as they happen (fed by the world's thread)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._changes: list[Change] = []

    def update(self, world: w.World) -> None:
        phase = classify(world)
        with self._lock:
            if not self._changes or self._changes[-1].phase != phase:
                self._changes.append(Change(world.now(), phase))

    def changes(self) -> list[Change]:
        with self._lock:
            return list(self._changes)

    def current(self) -> str:
        with self._lock:
            return self._changes[-1].phase if self._changes else "-"

    def sequence(self) -> list[str]:
        """The phases in order, without the in-between states and repeats: "ABCDEFA"."""
        out: list[str] = []
        for change in self.changes():
            if change.phase != "-" and (not out or out[-1] != change.phase):
                out.append(change.phase)
        return out
