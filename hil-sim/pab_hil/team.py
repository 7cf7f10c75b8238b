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
    speed: float = TARGET_SPEED  # mm/s

    def at(self, t: float) -> tuple[float, float]:
        """Where the target is at `t`: on its orbit, at its speed (a radius of 0: at the centre)."""
        if self.radius == 0.0:
            return self.centre
        angle = self.phase + self.speed * t / self.radius
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


# -- the team on the bus ----------------------------------------------------------------------------
# The identifiers of the multi-target observation network (three robots' base controllers, an
# override per observer gated by a BLE group per target); its closed-loop scenario needs BLE in
# the network language and on the boards, still on the branch of issue 12.

ROBOTS = {"r1": 1, "r2": 2, "r3": 3}  # node name -> node id (= the robot's number)
TARGETS = (1, 2, 3, 4)
BLE_PERIOD = 0.1  # s: the groups' period in the network file
OBSERVER_HZ = 20.0
WANDER_EVERY = 4  # wander publishes every 4th observer tick: 5 Hz


def observer_id(robot: int, target: int) -> int:
    """Topic obs_<robot><target>: observer `target` of `robot` (its BLE group's local topic)."""
    return 0x100 + 0x10 * robot + target


def wander_id(robot: int) -> int:
    return 0x200 + robot


def drive_id(robot: int) -> int:
    """What the robot's base node re-publishes from port r<robot>.drive: the delivered command."""
    return 0x300 + robot


def board_routes(robot: int) -> tuple[str, ...]:
    """cangw filters for a robot's base controller as the emulated board: its acceptance filter
    (`pab_hil.board.acceptance`) with, of the topics, only its own behaviours'. Its serial line
    carries a few hundred frames a second; the whole team's behaviours would saturate it, and a
    board's CAN acceptance filters do this job on a robot."""
    from .board import acceptance

    return acceptance(robot, topics=(
        f"{0x100 + 0x10 * robot:08X}:800007F0",  # obs_<robot>1..4 (standard frames only)
        f"{wander_id(robot):08X}:800007FF",
    ))


class TeamWorld:
    """The robots, the targets and the commands the base controllers delivered, shared by the
    harness's threads. Time is the world's own (seconds since it began), advanced by `step`.

    Free-running, robots move and targets orbit; `place` freezes a scene (robots stand where
    put, facing where put; targets stand still), so that eligibilities hold still while a test
    kills a node or sets up a tie."""

    def __init__(self, poses: dict[int, Pose], targets: tuple[Target, ...] | None = None,
                 seed: int = 1) -> None:
        import threading

        self._lock = threading.Lock()
        self.t = 0.0
        self.poses = dict(poses)
        self.targets = targets if targets is not None else default_targets()
        self.moving = True
        self._turn: dict[int, tuple[float, float]] = {}  # robot -> (deg/s, world time delivered)
        self._wander = {robot: Wander(seed * 100 + robot) for robot in poses}
        self._tick = 0

    def deliver(self, robot: int, command: Command) -> None:
        """A command robot's base controller delivered (re-published): it turns at its rate."""
        with self._lock:
            self._turn[robot] = (command.rotate, self.t)

    def place(self, poses: dict[int, Pose], targets: tuple[Target, ...]) -> None:
        """Freezes a scene: the robots in `poses` stand there, the targets where they are now;
        nothing moves any more."""
        with self._lock:
            self.poses.update(poses)
            self.targets = tuple(Target(x.number, x.at(self.t), 0.0, 0.0, speed=0.0)
                                 for x in targets)
            self.moving = False

    def step(self, dt: float) -> None:
        with self._lock:
            if self.moving:
                for robot, pose in self.poses.items():
                    rotate, at = self._turn.get(robot, (0.0, -1e9))
                    turn = rotate if self.t - at <= ROTATE_TIMEOUT else 0.0
                    self.poses[robot] = step(pose, turn, dt)
            self.t += dt

    def frames(self) -> list[tuple[int, bytes]]:
        """One tick of every behaviour of every robot (called at OBSERVER_HZ): each observer that
        sees its target, and every WANDER_EVERY ticks each wander."""
        with self._lock:
            tick, self._tick = self._tick, self._tick + 1
            out = []
            for robot, pose in self.poses.items():
                for target in self.targets:
                    command = observer_command(pose, target, self.t, robot, tick,
                                               0x10 * robot + target.number)
                    if command is not None:
                        out.append((observer_id(robot, target.number), command.encode()))
                if tick % WANDER_EVERY == 0:
                    out.append((wander_id(robot),
                                self._wander[robot].command(self.t, robot, tick, 0x10 * robot).encode()))
            return out

    def eligibilities(self) -> dict[tuple[int, int], int]:
        """(robot, target) -> the eligibility its observer publishes now (0: does not see it)."""
        with self._lock:
            return {(robot, x.number): eligibility(pose, x.at(self.t))
                    for robot, pose in self.poses.items() for x in self.targets}


# -- what the bus shows -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Drive:
    """Robot `robot` drives towards `target` (0: wanders) from `start` to `end` (kernel times)."""

    robot: int
    target: int
    start: float
    end: float


def drives(messages, robots: dict[str, int] = ROBOTS) -> list[Drive]:
    """From a candump log, who drove each robot when: each delivered command holds until the
    robot's next one, or for ROTATE_TIMEOUT (after which the robot goes straight), exactly as the
    world moves the robot. Consecutive commands for the same target merge into one Drive."""
    by_id = {drive_id(robot): robot for robot in robots.values()}
    out: list[Drive] = []
    current: dict[int, Drive] = {}
    for message in messages:
        if message.is_extended_id or message.arbitration_id not in by_id:
            continue
        command = Command.decode(bytes(message.data))
        if command is None:
            continue
        robot, at = by_id[message.arbitration_id], message.timestamp
        previous = current.get(robot)
        if previous is not None and previous.target == command.target and at <= previous.end:
            current[robot] = Drive(robot, command.target, previous.start, at + ROTATE_TIMEOUT)
            continue
        if previous is not None:
            out.append(Drive(robot, previous.target, previous.start, min(previous.end, at)))
        current[robot] = Drive(robot, command.target, at, at + ROTATE_TIMEOUT)
    out.extend(current.values())
    return sorted(out, key=lambda d: (d.start, d.robot))


def shared(drives_: list[Drive], target: int) -> list[tuple[float, float, tuple[int, ...]]]:
    """The intervals during which more than one robot drove towards `target`:
    (start, end, robots)."""
    edges = sorted({d.start for d in drives_ if d.target == target}
                   | {d.end for d in drives_ if d.target == target})
    out = []
    for start, end in zip(edges, edges[1:]):
        middle = (start + end) / 2
        robots = tuple(sorted(d.robot for d in drives_
                              if d.target == target and d.start <= middle < d.end))
        if len(robots) > 1:
            if out and out[-1][1] == start and out[-1][2] == robots:
                out[-1] = (out[-1][0], end, robots)
            else:
                out.append((start, end, robots))
    return out


def coverage(drives_: list[Drive], target: int, start: float, end: float) -> float:
    """The fraction of [start, end) during which some robot drove towards `target`."""
    spans = sorted((max(d.start, start), min(d.end, end)) for d in drives_
                   if d.target == target and d.end > start and d.start < end)
    covered, reach = 0.0, start
    for a, b in spans:
        if b > reach:
            covered += b - max(a, reach)
            reach = b
    return covered / (end - start) if end > start else 0.0
