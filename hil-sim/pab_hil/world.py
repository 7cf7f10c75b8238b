"""The world of "Take and Return": the robot's arm, hand and gaze, the object and the person.

The robot moves only on what its nodes deliver: the arm goes towards the last target the arm node
re-published (and holds still when none came for `ARM_COMMAND_TIMEOUT`), the hand opens or closes
as the hand node last told it, the eyes jump to the gaze node's target. The person follows a script
(`person.py`). Behaviours, in their own processes, read the world through `World.snapshot()` the
way they would read their sensors, and publish on the bus.

Distances are in millimetres in the robot's frame (x forward, y left, z up, head at the origin).
The state lives in a shared-memory array so that forked behaviour processes see it live.
"""

from __future__ import annotations

import math
import multiprocessing
import struct
import threading
import time
from dataclasses import dataclass, field

Vec = tuple[float, float, float]

# Where things are.
REST_POSE: Vec = (150.0, -200.0, -250.0)
OBJECT_SHOWN_AT: Vec = (350.0, 100.0, -50.0)
FACE_AT: Vec = (600.0, -250.0, 150.0)
GAZE_START: Vec = (600.0, 0.0, 0.0)
LOOK_AROUND_TARGETS: tuple[Vec, ...] = (
    (600.0, 250.0, 0.0),
    (600.0, 0.0, 0.0),
    (600.0, -250.0, 0.0),
    (600.0, 0.0, -150.0),
)

# How the robot and its sensors behave.
FIELD_OF_VIEW_DEG = 35.0  # half-angle of the camera's cone around the gaze direction
ARM_SPEED = 300.0  # mm/s towards the delivered target
ARM_COMMAND_TIMEOUT = 0.3  # s: the arm controller holds still without fresh targets
HAND_SPEED = 1 / 0.3  # closure per second: 0.3 s from open to closed
GRASP_REACH = 30.0  # mm: the open hand can grasp the object this close
RELEASE_REACH = 60.0  # mm: the hand holding the object points at the face this close
HANDOVER_REACH = 100.0  # mm: the person takes a released object this close to the face

# Who holds the object.
NOBODY = 0  # dropped: a failure
PERSON_SHOWS = 1  # the person holds it out to the robot
HAND = 2  # in the robot's hand
PERSON_KEEPS = 3  # the person has it and keeps it

HOLDERS = {NOBODY: "dropped", PERSON_SHOWS: "person (showing)", HAND: "hand", PERSON_KEEPS: "person"}

# The CAN ids of the gateways' re-published frames (the ports' `republish` in the network file).
ARM_TARGET_ID = 0x200
GAZE_TARGET_ID = 0x201
HAND_COMMAND_ID = 0x202

# Hand commands (byte 0 of grasp_cmd, release_cmd, rest_open).
OPEN = 0
CLOSE = 1

_FIELDS = (
    "t",
    "gaze_x", "gaze_y", "gaze_z",
    "hand_x", "hand_y", "hand_z",
    "closure",
    "object_x", "object_y", "object_z", "holder",
    "face_present",
)
_INDEX = {name: index for index, name in enumerate(_FIELDS)}


@dataclass(frozen=True)
class Snapshot:
    """What sensors see at one instant: read-only, consistent."""

    t: float
    gaze: Vec
    hand: Vec
    closure: float
    object: Vec
    holder: int
    face_present: bool

    @property
    def hand_open(self) -> bool:
        return self.closure < 0.1

    @property
    def hand_closed(self) -> bool:
        return self.closure > 0.9

    def in_view(self, point: Vec) -> bool:
        """Whether the camera, looking at `gaze`, sees `point`."""
        return angle_deg(self.gaze, point) <= FIELD_OF_VIEW_DEG


@dataclass
class Delivery:
    """One frame a node delivered (re-published), as the world received it."""

    time: float
    payload: bytes

    @property
    def origin(self) -> int:
        """The publishing behaviour's id (byte 7 of every behaviour frame)."""
        return self.payload[7] if len(self.payload) == 8 else -1


@dataclass
class Deliveries:
    arm: list[Delivery] = field(default_factory=list)
    gaze: list[Delivery] = field(default_factory=list)
    hand: list[Delivery] = field(default_factory=list)


class World:
    """The shared state, and its dynamics (stepped by the harness process only)."""

    def __init__(self) -> None:
        # A seqlock, not a lock: behaviour processes read while the harness writes, and a reader
        # killed mid-read (the tests kill behaviours) must not leave anything held. Slot 0 is the
        # sequence number, odd while a write is under way; the harness is the only writer.
        self._state = multiprocessing.RawArray("d", 1 + len(_FIELDS))
        self._write_lock = threading.Lock()  # the harness's writers (world and bus threads)
        self._lock = threading.Lock()  # guards the fields below (harness threads)
        self.epoch = time.time()
        self._bus_clock = -math.inf  # the latest kernel timestamp of a frame the harness heard
        self.deliveries = Deliveries()
        self._arm_target: Vec | None = None
        self._arm_target_time = -math.inf
        self._hand_command = OPEN
        self._person = None
        self._set_many(
            t=0.0,
            gaze=GAZE_START,
            hand=REST_POSE,
            closure=0.0,
            object=OBJECT_SHOWN_AT,
            holder=PERSON_KEEPS,
            face_present=0.0,
        )

    # -- reading (any process) -----------------------------------------------------------------

    def snapshot(self) -> Snapshot:
        while True:
            before = self._state[0]
            values = self._state[1:]
            if before == self._state[0] and int(before) % 2 == 0:
                break
            time.sleep(0)  # a write is under way: let the writer finish
        get = lambda name: values[_INDEX[name]]  # noqa: E731
        vec = lambda prefix: (get(prefix + "_x"), get(prefix + "_y"), get(prefix + "_z"))  # noqa: E731
        return Snapshot(
            t=get("t"),
            gaze=vec("gaze"),
            hand=vec("hand"),
            closure=get("closure"),
            object=vec("object"),
            holder=int(get("holder")),
            face_present=get("face_present") > 0.5,
        )

    def now(self) -> float:
        """Seconds since the world began (wall clock, the same as the bus timestamps')."""
        return time.time() - self.epoch

    # -- what the nodes deliver (the harness's bus thread) -------------------------------------

    def on_delivery(self, can_id: int, payload: bytes, timestamp: float) -> None:
        """A frame re-published by a node's gateway port: the robot obeys it."""
        at = timestamp - self.epoch
        with self._lock:
            self._bus_clock = max(self._bus_clock, timestamp)
            if can_id == ARM_TARGET_ID and len(payload) == 8:
                self.deliveries.arm.append(Delivery(at, payload))
                self._arm_target = decode_position(payload)
                self._arm_target_time = at
            elif can_id == GAZE_TARGET_ID and len(payload) == 8:
                self.deliveries.gaze.append(Delivery(at, payload))
                self._set_many(gaze=decode_position(payload))
            elif can_id == HAND_COMMAND_ID and len(payload) == 8:
                self.deliveries.hand.append(Delivery(at, payload))
                if payload[0] in (OPEN, CLOSE):
                    self._hand_command = payload[0]

    def on_bus_time(self, timestamp: float) -> None:
        """The harness heard a frame the kernel timestamped `timestamp` (wall clock)."""
        with self._lock:
            self._bus_clock = max(self._bus_clock, timestamp)

    def heard_until(self) -> float:
        """Seconds since the world began up to which the harness has heard the bus: now, unless
        its socket lags behind the bus (a loaded machine), then the time of the last frame it
        read. The nodes' heartbeats (4 Hz) keep it moving while the bus is otherwise quiet."""
        with self._lock:
            return min(self.now(), self._bus_clock - self.epoch)

    def last_delivery(self, port: str, within: float) -> Delivery | None:
        """The port's last delivery if it came less than `within` seconds before the bus time the
        harness has heard up to (see `heard_until`). Judged on bus time, not on the wall clock,
        so that a harness that reads the bus late does not take a stream of deliveries that
        never stopped on the bus for one that did."""
        heard = self.heard_until()
        with self._lock:
            frames = getattr(self.deliveries, port)
            if frames and heard - frames[-1].time <= within:
                return frames[-1]
            return None

    # -- the person's script (the harness) -----------------------------------------------------

    def set_person(self, person) -> None:
        self._person = person

    def show_object(self) -> None:
        self._set_many(holder=PERSON_SHOWS, object=OBJECT_SHOWN_AT)

    def person_takes_object(self) -> None:
        self._set_many(holder=PERSON_KEEPS)

    def person_enters(self) -> None:
        self._set_many(face_present=1.0)

    def person_leaves(self) -> None:
        self._set_many(face_present=0.0)

    # -- dynamics ------------------------------------------------------------------------------

    def step(self, dt: float) -> None:
        """Advances the robot and the object by `dt` seconds, then the person's script."""
        now = self.now()
        state = self.snapshot()
        with self._lock:
            target, target_time, command = self._arm_target, self._arm_target_time, self._hand_command
        hand = state.hand
        if target is not None and now - target_time <= ARM_COMMAND_TIMEOUT:
            hand = move_towards(hand, target, ARM_SPEED * dt)
        goal = 1.0 if command == CLOSE else 0.0
        closure = state.closure + max(-HAND_SPEED * dt, min(HAND_SPEED * dt, goal - state.closure))
        holder, obj = state.holder, state.object
        if holder == HAND:
            obj = hand
            if closure < 0.5:  # the hand opened: the person takes it, or it falls
                near_face = state.face_present and distance(hand, FACE_AT) <= HANDOVER_REACH
                holder = PERSON_KEEPS if near_face else NOBODY
        elif holder == PERSON_SHOWS and closure >= 1.0 and state.closure < 1.0:
            if distance(hand, obj) <= GRASP_REACH:  # closed around the object: the person lets go
                holder = HAND
                obj = hand
        self._set_many(t=now, hand=hand, closure=closure, holder=holder, object=obj)
        if self._person is not None:
            self._person.step(self, self.snapshot())

    def _set_many(self, **values) -> None:
        state = self._state
        with self._write_lock:
            state[0] += 1  # odd: readers retry
            for name, value in values.items():
                if isinstance(value, tuple):
                    for axis, component in zip("xyz", value):
                        state[1 + _INDEX[f"{name}_{axis}"]] = component
                else:
                    state[1 + _INDEX[name]] = float(value)
            state[0] += 1


# -- payloads ----------------------------------------------------------------------------------
# Every behaviour frame is 8 bytes: bytes 0-5 the content, byte 6 a sequence number of the
# publisher, byte 7 the publisher's id (as many robot middlewares stamp their messages). The
# gateways re-publish the payload unchanged, so the world can tell who drives each port, and the
# latency can be measured by matching payloads in the bus log.


def encode_position(point: Vec, sequence: int, origin: int) -> bytes:
    x, y, z = (max(-32768, min(32767, round(component))) for component in point)
    return struct.pack("<hhhBB", x, y, z, sequence & 0xFF, origin)


def decode_position(payload: bytes) -> Vec:
    x, y, z = struct.unpack_from("<hhh", payload)
    return (float(x), float(y), float(z))


def encode_command(command: int, sequence: int, origin: int) -> bytes:
    return struct.pack("<B5xBB", command, sequence & 0xFF, origin)


# -- geometry ----------------------------------------------------------------------------------


def distance(a: Vec, b: Vec) -> float:
    return math.dist(a, b)


def move_towards(position: Vec, target: Vec, step: float) -> Vec:
    gap = distance(position, target)
    if gap <= step or gap == 0.0:
        return target
    scale = step / gap
    return tuple(p + (t - p) * scale for p, t in zip(position, target))  # type: ignore[return-value]


def angle_deg(a: Vec, b: Vec) -> float:
    """The angle between the directions from the head (origin) to `a` and to `b`."""
    norm = math.hypot(*a) * math.hypot(*b)
    if norm == 0.0:
        return 180.0
    cosine = sum(p * q for p, q in zip(a, b)) / norm
    return math.degrees(math.acos(max(-1.0, min(1.0, cosine))))
