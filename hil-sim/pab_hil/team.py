"""The world of multi-target observation (W-CMOMMT, section 4 of the Ayllu paper): robots on a
plane keep prioritised moving targets in view, one robot per target, coordinated by their base
controllers' Broadcast of Local Eligibility.

Each robot drives forward at a constant speed (the paper's safe-velocity behaviour, reduced to a
bounce off the arena's walls) and turns at the rate its base controller last delivered (none for
`ROTATE_TIMEOUT`: it goes straight). Its camera sees a target within `CAMERA_RANGE` and
`CAMERA_HALF_ANGLE` of its heading. Behaviours read the world through `Team.snapshot()` and
publish frames, exactly as on the robots:

- observer k of robot i, while it sees target k: a rotation towards the target and, in the same
  frame, its eligibility for target k (higher when closer; the paper's "height of the target in
  the visual field");
- wander of robot i: a slow random rotation, always.

Who drives robot i is in each re-published frame (bytes 4 and 5): the harness judges coverage from
the bus, never by arbitrating itself.

Distances in millimetres, angles in degrees, time in seconds since the world began.
"""

from __future__ import annotations

import math
import random
import struct
from dataclasses import dataclass

ARENA = 6000.0  # mm: a square arena, walls at 0 and ARENA
SPEED = 250.0  # mm/s forward, always
ROTATE_TIMEOUT = 0.3  # s: without a fresh rotation the robot goes straight
MAX_TURN = 90.0  # deg/s
CAMERA_RANGE = 2500.0  # mm
CAMERA_HALF_ANGLE = 30.0  # deg
TURN_GAIN = 2.0  # deg/s of rotation per degree of bearing
TARGET_SPEED = 120.0  # mm/s along each target's orbit

# Frame layout of every behaviour frame (8 bytes): rotation (i16, centi-degrees per second),
# eligibility (u16; 0 for wander), the target observed (1..; 0 for wander), the robot, a sequence
# number, and the publisher's origin.
_LAYOUT = struct.Struct("<hHBBBB")
ELIGIBILITY_OFFSET = 2  # the BLE field: { offset = 2, size = 2 }


@dataclass(frozen=True)
class Command:
    rotate: float  # deg/s
    eligibility: int
    target: int  # 0: wander
    robot: int
    seq: int
    origin: int

    def encode(self) -> bytes:
        centi = max(-32768, min(32767, round(self.rotate * 100)))
        return _LAYOUT.pack(centi, self.eligibility, self.target, self.robot, self.seq & 0xFF,
                            self.origin)

    @staticmethod
    def decode(payload: bytes) -> "Command | None":
        if len(payload) != _LAYOUT.size:
            return None
        centi, eligibility, target, robot, seq, origin = _LAYOUT.unpack(payload)
        return Command(centi / 100, eligibility, target, robot, seq, origin)


@dataclass(frozen=True)
class Pose:
    x: float
    y: float
    heading: float  # deg, counter-clockwise from +x


@dataclass(frozen=True)
class Target:
    number: int  # 1 = highest priority
    centre: tuple[float, float]
    radius: float
    phase: float  # rad at t = 0

    def at(self, t: float) -> tuple[float, float]:
        """Where the target is at `t`: on its orbit, at TARGET_SPEED."""
        angle = self.phase + TARGET_SPEED * t / self.radius
        return (self.centre[0] + self.radius * math.cos(angle),
                self.centre[1] + self.radius * math.sin(angle))


def default_targets() -> tuple[Target, ...]:
    """Four targets, one per quadrant, orbiting slowly."""
    return (
        Target(1, (1500.0, 1500.0), 600.0, 0.0),
        Target(2, (4500.0, 1500.0), 600.0, math.pi / 2),
        Target(3, (4500.0, 4500.0), 600.0, math.pi),
        Target(4, (1500.0, 4500.0), 600.0, 3 * math.pi / 2),
    )


def bearing(pose: Pose, point: tuple[float, float]) -> float:
    """The angle from the robot's heading to `point`, in [-180, 180) degrees."""
    angle = math.degrees(math.atan2(point[1] - pose.y, point[0] - pose.x)) - pose.heading
    return (angle + 180.0) % 360.0 - 180.0


def sees(pose: Pose, point: tuple[float, float]) -> bool:
    distance = math.hypot(point[0] - pose.x, point[1] - pose.y)
    return distance <= CAMERA_RANGE and abs(bearing(pose, point)) <= CAMERA_HALF_ANGLE


def eligibility(pose: Pose, point: tuple[float, float]) -> int:
    """1..1000 for a target in view, higher when closer; 0 out of view."""
    if not sees(pose, point):
        return 0
    distance = math.hypot(point[0] - pose.x, point[1] - pose.y)
    return max(1, round(1000 * (1 - distance / CAMERA_RANGE)))


def step(pose: Pose, turn: float, dt: float) -> Pose:
    """The robot after `dt` seconds turning at `turn` deg/s (clamped) and driving forward; at a
    wall it bounces (its heading reflected), staying inside the arena."""
    turn = max(-MAX_TURN, min(MAX_TURN, turn))
    heading = pose.heading + turn * dt
    x = pose.x + SPEED * dt * math.cos(math.radians(heading))
    y = pose.y + SPEED * dt * math.sin(math.radians(heading))
    if not 0.0 <= x <= ARENA:
        heading = 180.0 - heading
        x = min(ARENA, max(0.0, x))
    if not 0.0 <= y <= ARENA:
        heading = -heading
        y = min(ARENA, max(0.0, y))
    return Pose(x, y, heading % 360.0)


def observer_command(pose: Pose, target: Target, t: float, robot: int, seq: int,
                     origin: int) -> Command | None:
    """What observer `target.number` of `robot` publishes at `t`: None while it does not see it."""
    where = target.at(t)
    if not sees(pose, where):
        return None
    rotate = max(-MAX_TURN, min(MAX_TURN, TURN_GAIN * bearing(pose, where)))
    return Command(rotate, eligibility(pose, where), target.number, robot, seq, origin)


class Wander:
    """A slow random rotation that changes every second, seeded per robot."""

    def __init__(self, seed: int) -> None:
        self._random = random.Random(seed)
        self._second = -1
        self._rotate = 0.0

    def command(self, t: float, robot: int, seq: int, origin: int) -> Command:
        second = int(t)
        while self._second < second:
            self._second += 1
            self._rotate = self._random.uniform(-20.0, 20.0)
        return Command(self._rotate, 0, 0, robot, seq, origin)
