"""Schemas as the schema server takes them: the types of `pab_core::schema`, their postcard
encoding, and the builders of `pab_core::schema::build` (the paper's API calls).

A schema is one action primitive and a prioritised reaction table (an event, and where the next
schema comes from). The classes mirror the Rust enums variant for variant, under the same names:
``Action.MoveTo(goal=..., speed=...)``, ``Event.Above(Measure.Contact(), 3000)``,
``Source.Queue()``. Their encoding is postcard's, byte for byte what the Rust builders produce
(``tests/golden_schemas.json``, generated and checked by ``core/tests/schema_golden.rs``, holds
the proof):

- an enum: its variant index (declaration order) as a varint, then its fields;
- ``u16``/``u32`` (and a list's length): unsigned LEB128 varint; ``i32``: zigzag, then varint;
- ``u8``: one byte; a pose ``[i32; 6]``: six values, no length;
- a struct: its fields in order.

**Units** are the board's, integers throughout: positions µm on x, y, z and µrad about x, y, z
(a pose is six values); speeds µm/s (µrad/s for a purely rotational move); forces mN, torques
mN·m; times ms; stiffness N/m, damping N·s/m. The helpers :func:`mm`, :func:`newtons`,
:func:`mrad` and :func:`pose_mm` convert from the network file's units (mm, mm/s, N, mrad),
rounding as `pab-lang` does (half away from zero).

The server refuses a schema whose values are out of its ranges (:meth:`Schema.check` says what
it would answer); the classes here only refuse what cannot be encoded at all (a value outside
its integer type, more than 16 reactions).

:class:`Limits` (with its :class:`Joint` entries) are the board's safety bounds,
`pab_core::schema::Limits`, which the SchemaTransfer's limits channel carries in the same
encoding (``Client.set_limits``); ``tests/golden_schemas.json`` holds Rust's bytes for them too.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any, ClassVar, Iterable, Optional, Sequence, Tuple

from .protocol import SchemaOutcome

#: Axes of a pose: x, y, z (µm), then rotations about x, y, z (µrad).
AXES = 6
#: Reactions a schema holds at most.
MAX_REACTIONS = 16
#: Schemas the board's queue holds: a full queue refuses (``QueueFull``), never overwrites.
QUEUE_DEPTH = 8
#: Extra sensors a board reads (``Measure.Sensor`` indices are below this).
MAX_SENSORS = 8
#: The largest coordinate, speed, distance or time a schema may carry (µm, µrad, ms: 500 m).
MAX_COORD = 500_000_000
#: The longest encoded schema a board takes.
MAX_ENCODED = 256
#: Ids from here up name the server's own schemas; a client's are below.
BUILTIN_IDS = 0xFF00
#: The built-in schema installed from an empty queue (idle until the queue is not empty).
WAIT_QUEUE = 0xFF00
#: The built-in schema that waits for the high-priority channel.
WAIT_HIGH_PRIORITY = 0xFF01
#: The built-in recovery after a safety event is ``SAFETY + cause`` (``SchemaSafety``).
SAFETY = 0xFF10

U8_MAX = 0xFF
U16_MAX = 0xFFFF
U32_MAX = 0xFFFF_FFFF
I32_MIN = -(2**31)
I32_MAX = 2**31 - 1


class DecodeError(ValueError):
    """Bytes that are not exactly one schema's postcard encoding. ``outcome`` is what the board
    answers for them: ``Malformed`` or ``TrailingBytes``."""

    def __init__(self, message: str, outcome: SchemaOutcome = SchemaOutcome.Malformed):
        super().__init__(message)
        self.outcome = outcome


# ---------------------------------------------------------------------------------------------
# postcard


def _int(value: Any, lo: int, hi: int, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{what}: an integer is needed, not {value!r} (units: µm, µrad, mN, ms)")
    if not lo <= value <= hi:
        raise ValueError(f"{what}: {value} is outside {lo}..={hi}")
    return value


class _Writer:
    def __init__(self) -> None:
        self.out = bytearray()

    def varint(self, value: int) -> None:
        while True:
            byte = value & 0x7F
            value >>= 7
            if value:
                self.out.append(byte | 0x80)
            else:
                self.out.append(byte)
                return

    def u8(self, value: int) -> None:
        self.out.append(value)

    def i32(self, value: int) -> None:
        # Zigzag: 0, -1, 1, -2 ... as 0, 1, 2, 3 ...
        self.varint(((value << 1) ^ (value >> 31)) & U32_MAX)


class _Reader:
    """postcard's reading, as `pab_core::wire::Reader` does it (the board's decoder)."""

    def __init__(self, data: bytes) -> None:
        self.data = bytes(data)
        self.at = 0

    def u8(self) -> int:
        if self.at >= len(self.data):
            raise DecodeError("unexpected end")
        byte = self.data[self.at]
        self.at += 1
        return byte

    def varint(self, bits: int) -> int:
        # At most ceil(bits / 7) bytes; the last byte of a full-length one no larger than the
        # bits left.
        max_bytes = -(-bits // 7)
        last_max = (1 << (bits % 7)) - 1
        out = 0
        for i in range(max_bytes):
            byte = self.u8()
            out |= (byte & 0x7F) << (7 * i)
            if byte & 0x80 == 0:
                if i == max_bytes - 1 and byte > last_max:
                    break
                return out
        raise DecodeError("bad varint")

    def u16(self) -> int:
        return self.varint(16)

    def u32(self) -> int:
        return self.varint(32)

    def i32(self) -> int:
        z = self.u32()
        return (z >> 1) ^ -(z & 1)

    def variant(self, count: int, what: str) -> int:
        index = self.u32()
        if index >= count:
            raise DecodeError(f"{what}: unknown variant {index}")
        return index

    def length(self) -> int:
        n = self.varint(64)
        if n > U32_MAX:
            raise DecodeError("list length beyond u32")
        return n


def _pose(values: Iterable[int], what: str) -> Tuple[int, ...]:
    p = tuple(values)
    if len(p) == 3:
        p = p + (0, 0, 0)
    if len(p) != AXES:
        raise ValueError(f"{what}: a pose is 3 values (x, y, z µm) or 6 (and µrad about x, y, z)")
    return tuple(_int(c, I32_MIN, I32_MAX, what) for c in p)


# ---------------------------------------------------------------------------------------------
# The types, variant for variant as in core/src/schema/{action,event,message}.rs.


class _Variant:
    """One variant of an enum: its index, and its fields in declaration order with their kind
    (``u8``, ``u32``, ``i32``, ``pose``, or a nested enum's base class)."""

    INDEX: ClassVar[int]
    FIELDS: ClassVar[Tuple[Tuple[str, Any], ...]] = ()

    def __post_init__(self) -> None:
        for name, kind in self.FIELDS:
            value = getattr(self, name)
            what = f"{type(self).__qualname__}.{name}"
            if kind == "u8":
                value = _int(value, 0, U8_MAX, what)
            elif kind == "u32":
                value = _int(value, 0, U32_MAX, what)
            elif kind == "i32":
                value = _int(value, I32_MIN, I32_MAX, what)
            elif kind == "pose":
                value = _pose(value, what)
            elif kind is Gripper:
                value = Gripper(value)
            elif not isinstance(value, kind):
                raise TypeError(f"{what}: a {kind.__name__} is needed, not {value!r}")
            object.__setattr__(self, name, value)

    def _encode(self, w: _Writer) -> None:
        w.varint(self.INDEX)
        for name, kind in self.FIELDS:
            value = getattr(self, name)
            if kind == "u8":
                w.u8(value)
            elif kind == "u32":
                w.varint(value)
            elif kind == "i32":
                w.i32(value)
            elif kind == "pose":
                for c in value:
                    w.i32(c)
            elif kind is Gripper:
                w.varint(int(value))
            else:
                value._encode(w)

    @classmethod
    def _decode_fields(cls, r: _Reader) -> "_Variant":
        values = []
        for _name, kind in cls.FIELDS:
            if kind == "u8":
                values.append(r.u8())
            elif kind == "u32":
                values.append(r.u32())
            elif kind == "i32":
                values.append(r.i32())
            elif kind == "pose":
                values.append(tuple(r.i32() for _ in range(AXES)))
            elif kind is Gripper:
                values.append(Gripper(r.variant(2, "Gripper")))
            else:
                values.append(kind._decode(r))
        return cls(*values)

    def _to_json(self) -> Any:
        name = type(self).__name__
        if not self.FIELDS:
            return name
        values = [_json_value(getattr(self, n)) for n, _ in self.FIELDS]
        if self._TUPLE:
            return {name: values[0] if len(values) == 1 else values}
        return {name: {n: v for (n, _), v in zip(self.FIELDS, values)}}

    _TUPLE: ClassVar[bool] = False


def _json_value(value: Any) -> Any:
    if isinstance(value, Gripper):
        return value.name
    if isinstance(value, tuple):
        return list(value)
    if isinstance(value, _Variant):
        return value._to_json()
    return value


class _Enum:
    """The base of an enum's variants: decoding by variant index."""

    VARIANTS: ClassVar[Tuple[type, ...]] = ()

    @classmethod
    def _decode(cls, r: _Reader) -> Any:
        index = r.variant(len(cls.VARIANTS), cls.__name__)
        return cls.VARIANTS[index]._decode_fields(r)

    @classmethod
    def from_json(cls, value: Any) -> Any:
        """The variant from serde_json's form of the Rust value (externally tagged: ``"Done"``,
        ``{"Elapsed": 500}``, ``{"MoveTo": {"goal": [...], "speed": 1000}}``)."""
        if isinstance(value, str):
            name, body = value, None
        elif isinstance(value, dict) and len(value) == 1:
            ((name, body),) = value.items()
        else:
            raise ValueError(f"{cls.__name__}: not a variant: {value!r}")
        variant = getattr(cls, name, None)
        if variant not in cls.VARIANTS:
            raise ValueError(f"{cls.__name__}: unknown variant {name!r}")
        if not variant.FIELDS:
            return variant()
        if variant._TUPLE:
            items = [body] if len(variant.FIELDS) == 1 else list(body)
        else:
            items = [body[n] for n, _ in variant.FIELDS]
        args = []
        for (_, kind), item in zip(variant.FIELDS, items):
            if kind is Gripper:
                args.append(Gripper[item])
            elif isinstance(kind, type) and issubclass(kind, _Enum):
                args.append(kind.from_json(item))
            else:
                args.append(tuple(item) if kind == "pose" else item)
        return variant(*args)


def _variants(base: type, *classes: type) -> None:
    """Attaches `classes` to `base` as ``base.Name``, in declaration order (their indices)."""
    for index, cls in enumerate(classes):
        cls.INDEX = index
        cls.__qualname__ = f"{base.__name__}.{cls.__name__}"
        setattr(base, cls.__name__, cls)
    base.VARIANTS = classes


class Gripper(enum.IntEnum):
    """A gripper command (`pab_core::schema::Gripper`)."""

    Open = 0
    Closed = 1


class Measure(_Enum):
    """One value of the sensor table an event compares with a threshold."""


@dataclass(frozen=True)
class Position(Measure, _Variant):
    """The measured pose on one axis (0..6: x, y, z µm, then µrad about x, y, z)."""

    axis: int
    FIELDS = (("axis", "u8"),)
    _TUPLE = True


@dataclass(frozen=True)
class Displacement(Measure, _Variant):
    """The measured pose on one axis minus its value when the schema was installed."""

    axis: int
    FIELDS = (("axis", "u8"),)
    _TUPLE = True


@dataclass(frozen=True)
class Force(Measure, _Variant):
    """The measured wrench on one axis: mN (0..3), mN·m (3..6)."""

    axis: int
    FIELDS = (("axis", "u8"),)
    _TUPLE = True


@dataclass(frozen=True)
class Contact(Measure, _Variant):
    """The force against the current action's direction of motion, mN."""


@dataclass(frozen=True)
class Sensor(Measure, _Variant):
    """One of the board's extra sensors (0..8), in its topic's unit."""

    index: int
    FIELDS = (("index", "u8"),)
    _TUPLE = True


_variants(Measure, Position, Displacement, Force, Contact, Sensor)


class Event(_Enum):
    """A sensory event: it holds or not, at each tick."""


@dataclass(frozen=True)
class OneShot(Event, _Variant):
    """The current action has run at least one iteration."""


@dataclass(frozen=True)
class Done(Event, _Variant):
    """The current action is finished (a move on its goal, an idle's time out, ...)."""


@dataclass(frozen=True)
class Elapsed(Event, _Variant):
    """At least this many ms since the schema was installed."""

    ms: int
    FIELDS = (("ms", "u32"),)
    _TUPLE = True


@dataclass(frozen=True)
class QueueReady(Event, _Variant):
    """The queue holds a schema."""


@dataclass(frozen=True)
class Above(Event, _Variant):
    """The measure is at least the threshold."""

    measure: Measure
    threshold: int
    FIELDS = (("measure", Measure), ("threshold", "i32"))
    _TUPLE = True


@dataclass(frozen=True)
class Below(Event, _Variant):
    """The measure is at most the threshold."""

    measure: Measure
    threshold: int
    FIELDS = (("measure", Measure), ("threshold", "i32"))
    _TUPLE = True


_variants(Event, OneShot, Done, Elapsed, QueueReady, Above, Below)


class Source(_Enum):
    """Where the next schema comes from."""


@dataclass(frozen=True)
class Innate(Source, _Variant):
    """An innate schema of the board's set-up, by index."""

    index: int
    FIELDS = (("index", "u8"),)
    _TUPLE = True


@dataclass(frozen=True)
class Queue(Source, _Variant):
    """The next schema the client queued (with the queue empty, a wait until it is not)."""


@dataclass(frozen=True)
class HighPriority(Source, _Variant):
    """A wait for the high-priority channel: the client decides."""


_variants(Source, Innate, Queue, HighPriority)


class Action(_Enum):
    """One action primitive and its parameters (µm, µrad, µm/s, ms)."""


@dataclass(frozen=True)
class Idle(Action, _Variant):
    """Keep the command; done after `ms` (never, with 0)."""

    ms: int = 0
    FIELDS = (("ms", "u32"),)


@dataclass(frozen=True)
class _GripperAction(Action, _Variant):
    """Open or close the gripper (atomic)."""

    gripper: Gripper
    FIELDS = (("gripper", Gripper),)
    _TUPLE = True


_GripperAction.__name__ = "Gripper"


@dataclass(frozen=True)
class SetImpedance(Action, _Variant):
    """Set the drive's impedance (atomic): stiffness N/m, damping N·s/m."""

    stiffness: int
    damping: int
    FIELDS = (("stiffness", "u32"), ("damping", "u32"))


@dataclass(frozen=True)
class Relieve(Action, _Variant):
    """Set the attractor to the measured pose (atomic): relieves every force."""


@dataclass(frozen=True)
class MoveTo(Action, _Variant):
    """Move the attractor in a straight line to `goal` (µm, µrad) at `speed` µm/s."""

    goal: Tuple[int, ...]
    speed: int
    FIELDS = (("goal", "pose"), ("speed", "u32"))


@dataclass(frozen=True)
class MoveToTouch(Action, _Variant):
    """Move along `direction` (only its direction counts) at `speed` µm/s, at most `distance`
    µm."""

    direction: Tuple[int, ...]
    speed: int
    distance: int
    FIELDS = (("direction", "pose"), ("speed", "u32"), ("distance", "u32"))


@dataclass(frozen=True)
class BlindSearch(Action, _Variant):
    """Press `preload` µm into the surface and slide in a square spiral of `pitch` µm at
    `speed` µm/s, rocking about z by ±`wobble` µrad with period `wobble_ms`; `radius` µm is the
    half-width the watchdog's budget is made for."""

    preload: int
    pitch: int
    speed: int
    radius: int
    wobble: int
    wobble_ms: int
    FIELDS = (
        ("preload", "u32"),
        ("pitch", "u32"),
        ("speed", "u32"),
        ("radius", "u32"),
        ("wobble", "u32"),
        ("wobble_ms", "u32"),
    )


@dataclass(frozen=True)
class Grasp(Action, _Variant):
    """Close the gripper, done after `settle_ms`."""

    settle_ms: int
    FIELDS = (("settle_ms", "u32"),)


@dataclass(frozen=True)
class Release(Action, _Variant):
    """Open the gripper, done after `settle_ms`."""

    settle_ms: int
    FIELDS = (("settle_ms", "u32"),)


_variants(
    Action,
    Idle,
    _GripperAction,
    SetImpedance,
    Relieve,
    MoveTo,
    MoveToTouch,
    BlindSearch,
    Grasp,
    Release,
)


@dataclass(frozen=True)
class Reaction:
    """When `event` holds, install a schema from `next`."""

    event: Event
    next: Source

    def __post_init__(self) -> None:
        if not isinstance(self.event, Event) or not isinstance(self.next, Source):
            raise TypeError("Reaction(event: Event, next: Source)")


@dataclass(frozen=True)
class Schema:
    """One action primitive and its reaction table, in priority order (the first event that
    holds wins; the board's safety events come before them all).

    `id` is the client's name for it (below 0xFF00), echoed in every report about it;
    `watchdog_ms` its budget, 0 for the board's default (1.5 × the action's nominal time plus a
    margin)."""

    id: int
    action: Action
    reactions: Tuple[Reaction, ...] = ()
    watchdog_ms: int = 0

    def __post_init__(self) -> None:
        _int(self.id, 0, U16_MAX, "Schema.id")
        _int(self.watchdog_ms, 0, U32_MAX, "Schema.watchdog_ms")
        if not isinstance(self.action, Action):
            raise TypeError(f"Schema.action: an Action is needed, not {self.action!r}")
        reactions = tuple(self.reactions)
        if len(reactions) > MAX_REACTIONS:
            raise ValueError(f"a schema holds at most {MAX_REACTIONS} reactions")
        for r in reactions:
            if not isinstance(r, Reaction):
                raise TypeError(f"Schema.reactions: Reactions are needed, not {r!r}")
        object.__setattr__(self, "reactions", reactions)

    def encode(self) -> bytes:
        """postcard's encoding: what follows the channel byte in a SchemaTransfer message."""
        w = _Writer()
        w.varint(self.id)
        self.action._encode(w)
        w.varint(len(self.reactions))
        for r in self.reactions:
            r.event._encode(w)
            r.next._encode(w)
        w.varint(self.watchdog_ms)
        return bytes(w.out)

    @staticmethod
    def decode(data: bytes) -> "Schema":
        """Exactly one schema from its encoding (:class:`DecodeError` otherwise). Checks the
        encoding only; :meth:`check` says whether the board would take it."""
        r = _Reader(data)
        sid = r.u16()
        action = Action._decode(r)
        n = r.length()
        if n > MAX_REACTIONS:
            raise DecodeError(f"{n} reactions: at most {MAX_REACTIONS}")
        reactions = tuple(Reaction(Event._decode(r), Source._decode(r)) for _ in range(n))
        watchdog = r.u32()
        if r.at != len(r.data):
            raise DecodeError(
                f"{len(r.data) - r.at} bytes after the schema", SchemaOutcome.TrailingBytes
            )
        return Schema(sid, action, reactions, watchdog)

    def check(self) -> Optional[SchemaOutcome]:
        """What the board answers for this schema as `pab_core::schema::Schema::check` decides
        it: None when it takes it, else ``ReservedId``, ``BadAxis``, ``BadSensor``,
        ``OutOfRange`` or ``Degenerate`` (the queue's answers, ``QueueFull`` and the others,
        depend on the board's state)."""
        if self.id >= BUILTIN_IDS:
            return SchemaOutcome.ReservedId
        outcome = _check_action(self.action)
        if outcome is not None:
            return outcome
        for r in self.reactions:
            if isinstance(r.event, (Above, Below)):
                m = r.event.measure
                if isinstance(m, (Position, Displacement, Force)) and m.axis >= AXES:
                    return SchemaOutcome.BadAxis
                if isinstance(m, Sensor) and m.index >= MAX_SENSORS:
                    return SchemaOutcome.BadSensor
        return None

    def to_json(self) -> dict:
        """serde_json's form of the Rust value (as in ``tests/golden_schemas.json``)."""
        return {
            "id": self.id,
            "action": self.action._to_json(),
            "reactions": [
                {"event": r.event._to_json(), "next": r.next._to_json()} for r in self.reactions
            ],
            "watchdog_ms": self.watchdog_ms,
        }

    @staticmethod
    def from_json(value: dict) -> "Schema":
        """The schema from serde_json's form of the Rust value."""
        return Schema(
            value["id"],
            Action.from_json(value["action"]),
            tuple(
                Reaction(Event.from_json(r["event"]), Source.from_json(r["next"]))
                for r in value["reactions"]
            ),
            value["watchdog_ms"],
        )


def _check_action(a: Action) -> Optional[SchemaOutcome]:
    def within(*values: int) -> bool:
        return all(v <= MAX_COORD for v in values)

    def pose_within(p: Sequence[int]) -> bool:
        return all(abs(c) <= MAX_COORD for c in p)

    degenerate = False
    if isinstance(a, Idle):
        ranged = within(a.ms)
    elif isinstance(a, (Grasp, Release)):
        ranged = within(a.settle_ms)
    elif isinstance(a, (_GripperAction, Relieve)):
        ranged = True
    elif isinstance(a, SetImpedance):
        ranged = within(a.stiffness, a.damping)
    elif isinstance(a, MoveTo):
        ranged = pose_within(a.goal) and within(a.speed)
        degenerate = a.speed == 0
    elif isinstance(a, MoveToTouch):
        ranged = pose_within(a.direction) and within(a.speed, a.distance)
        degenerate = a.speed == 0 or tuple(a.direction[:3]) == (0, 0, 0)
    elif isinstance(a, BlindSearch):
        ranged = within(a.preload, a.pitch, a.speed, a.radius, a.wobble, a.wobble_ms)
        degenerate = a.speed == 0 or a.pitch == 0 or (a.wobble != 0 and a.wobble_ms == 0)
    else:  # pragma: no cover - every variant is above
        raise TypeError(a)
    if not ranged:
        return SchemaOutcome.OutOfRange
    if degenerate:
        return SchemaOutcome.Degenerate
    return None


# ---------------------------------------------------------------------------------------------
# The safety bounds of core/src/schema/limits.rs.

#: Joints a board's limits bound: one per extra sensor at most.
MAX_JOINTS = MAX_SENSORS


@dataclass(frozen=True)
class Joint:
    """One joint's bounds (`pab_core::schema::Joint`), in the counts of the extra sensor that
    reads its position: its range `min` ..= `max`, and its top speed `rate` in counts per
    second (0: none)."""

    sensor: int
    min: int
    max: int
    rate: int = 0

    def __post_init__(self) -> None:
        _int(self.sensor, 0, U8_MAX, "Joint.sensor")
        _int(self.min, I32_MIN, I32_MAX, "Joint.min")
        _int(self.max, I32_MIN, I32_MAX, "Joint.max")
        _int(self.rate, 0, U32_MAX, "Joint.rate")


_NEW_WORKSPACE = 1_000_000


@dataclass(frozen=True)
class Limits:
    """A board's safety bounds (`pab_core::schema::Limits`): the workspace's corners (µm,
    µrad: six values each), the limits on the force's and torque's magnitudes (mN, mN·m), the
    highest contact force a schema may wait for (mN), the measured pose's top speed (µm/s) and
    rate (µrad/s), and each joint's range and speed. A limit of 0 is none, except the force
    limit, which a board always has. The defaults are `Limits::new()`: ±1 m (rad), 50 N, no
    other bound.

    The table carries the loosest bounds a board may run with; at run time a client may set
    others (``Client.set_limits``), each within the table's: tighter, or back up to the
    table's, never looser (:meth:`check_within` says what the board answers)."""

    workspace_min: Tuple[int, ...] = (-_NEW_WORKSPACE,) * AXES
    workspace_max: Tuple[int, ...] = (_NEW_WORKSPACE,) * AXES
    force_limit: int = 50_000
    torque_limit: int = 0
    contact_limit: int = 0
    speed_limit: int = 0
    rate_limit: int = 0
    joints: Tuple[Joint, ...] = ()

    def __post_init__(self) -> None:
        for name in ("workspace_min", "workspace_max"):
            corner = tuple(getattr(self, name))
            if len(corner) != AXES:
                raise ValueError(
                    f"Limits.{name}: a corner is 6 values (x, y, z µm, then µrad about x, y, z)"
                )
            for c in corner:
                _int(c, I32_MIN, I32_MAX, f"Limits.{name}")
            object.__setattr__(self, name, corner)
        for name in ("force_limit", "torque_limit", "contact_limit", "speed_limit", "rate_limit"):
            _int(getattr(self, name), 0, U32_MAX, f"Limits.{name}")
        joints = tuple(self.joints)
        if len(joints) > MAX_JOINTS:
            raise ValueError(f"limits bound at most {MAX_JOINTS} joints")
        for j in joints:
            if not isinstance(j, Joint):
                raise TypeError(f"Limits.joints: Joints are needed, not {j!r}")
        object.__setattr__(self, "joints", joints)

    def encode(self) -> bytes:
        """postcard's encoding (the fields in order; the joints a length, then each one's
        sensor byte, min, max and rate): what follows the channel byte on the limits
        channel."""
        w = _Writer()
        for c in self.workspace_min + self.workspace_max:
            w.i32(c)
        for limit in (
            self.force_limit,
            self.torque_limit,
            self.contact_limit,
            self.speed_limit,
            self.rate_limit,
        ):
            w.varint(limit)
        w.varint(len(self.joints))
        for j in self.joints:
            w.u8(j.sensor)
            w.i32(j.min)
            w.i32(j.max)
            w.varint(j.rate)
        return bytes(w.out)

    @staticmethod
    def decode(data: bytes) -> "Limits":
        """Exactly one Limits from its encoding (:class:`DecodeError` otherwise, with the
        board's answer: ``Malformed``, or ``TrailingBytes``). Not checked: see
        :meth:`check_within`."""
        r = _Reader(data)
        low = tuple(r.i32() for _ in range(AXES))
        high = tuple(r.i32() for _ in range(AXES))
        limits = [r.u32() for _ in range(5)]
        n = r.length()
        if n > MAX_JOINTS:
            raise DecodeError(f"{n} joints: at most {MAX_JOINTS}")
        joints = tuple(Joint(r.u8(), r.i32(), r.i32(), r.u32()) for _ in range(n))
        if r.at != len(r.data):
            raise DecodeError(
                f"{len(r.data) - r.at} bytes after the limits", SchemaOutcome.TrailingBytes
            )
        return Limits(low, high, *limits, joints)

    def check(self) -> Optional[SchemaOutcome]:
        """Whether the bounds are consistent, as `Limits::check` decides it: None, or
        ``Looser`` (the board's answer) for a lower corner above its upper one, a force limit
        of 0, or a joint whose min is above its max."""
        crossed = any(lo > hi for lo, hi in zip(self.workspace_min, self.workspace_max))
        if crossed or self.force_limit == 0 or any(j.min > j.max for j in self.joints):
            return SchemaOutcome.Looser
        return None

    def check_within(self, table: "Limits") -> Optional[SchemaOutcome]:
        """What the board answers for these limits when its table's are `table`
        (`Limits::check_within`): None when it takes them, ``Looser`` when they are
        inconsistent (:meth:`check`) or looser than the table's somewhere: a corner or a
        joint's range beyond the table's, a limit above the table's (or none where the table
        has one), other joints than the table's (the same sensors, in the same order)."""
        if self.check() is not None:
            return SchemaOutcome.Looser

        def within(new: int, old: int) -> bool:
            # 0 is none: none is within none only.
            return old == 0 or 0 < new <= old

        joints = len(self.joints) == len(table.joints) and all(
            new.sensor == old.sensor
            and new.min >= old.min
            and new.max <= old.max
            and within(new.rate, old.rate)
            for new, old in zip(self.joints, table.joints)
        )
        inside = (
            all(n >= o for n, o in zip(self.workspace_min, table.workspace_min))
            and all(n <= o for n, o in zip(self.workspace_max, table.workspace_max))
            and joints
            and within(self.force_limit, table.force_limit)
            and within(self.torque_limit, table.torque_limit)
            and within(self.contact_limit, table.contact_limit)
            and within(self.speed_limit, table.speed_limit)
            and within(self.rate_limit, table.rate_limit)
        )
        return None if inside else SchemaOutcome.Looser

    def to_json(self) -> dict:
        """serde_json's form of the Rust value (as in ``tests/golden_schemas.json``)."""
        return {
            "workspace_min": list(self.workspace_min),
            "workspace_max": list(self.workspace_max),
            "force_limit": self.force_limit,
            "torque_limit": self.torque_limit,
            "contact_limit": self.contact_limit,
            "speed_limit": self.speed_limit,
            "rate_limit": self.rate_limit,
            "joints": [
                {"sensor": j.sensor, "min": j.min, "max": j.max, "rate": j.rate}
                for j in self.joints
            ],
        }

    @staticmethod
    def from_json(value: dict) -> "Limits":
        """The limits from serde_json's form of the Rust value."""
        return Limits(
            tuple(value["workspace_min"]),
            tuple(value["workspace_max"]),
            value["force_limit"],
            value["torque_limit"],
            value["contact_limit"],
            value["speed_limit"],
            value["rate_limit"],
            tuple(Joint(j["sensor"], j["min"], j["max"], j["rate"]) for j in value["joints"]),
        )


# ---------------------------------------------------------------------------------------------
# Units


def _round(x: float) -> int:
    """Half away from zero, as Rust's f64::round (Python's round() goes to even)."""
    if not math.isfinite(x):
        raise ValueError(f"{x} is not a finite number")
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


def mm(value: float) -> int:
    """mm (or mm/s) to µm (µm/s), rounded as the network file's calls are."""
    return _round(value * 1000.0)


def newtons(value: float) -> int:
    """N to mN."""
    return _round(value * 1000.0)


def mrad(value: float) -> int:
    """mrad to µrad."""
    return _round(value * 1000.0)


def pose_mm(x: float, y: float, z: float, rx: float = 0, ry: float = 0, rz: float = 0):
    """A pose from mm (x, y, z) and mrad (about x, y, z): six integers, µm and µrad, as the
    network file's ``[client.places]`` become."""
    return (mm(x), mm(y), mm(z), mrad(rx), mrad(ry), mrad(rz))


# ---------------------------------------------------------------------------------------------
# The builders of core/src/schema/build.rs, with the network file's defaults
# (lang/src/network/schema.rs, `Defaults`).


def _schema(id: int, action: Action, reactions: Sequence[Reaction], watchdog_ms: int) -> Schema:
    return Schema(id, action, tuple(reactions), watchdog_ms)


def move_to(id: int, goal: Sequence[int], speed: int = 50_000, *, watchdog_ms: int = 0) -> Schema:
    """``moveTo(pose)``: the attractor to `goal` (µm, µrad; three values are x, y, z) in a
    straight line at `speed` µm/s (default 50 mm/s); then the next queued schema.
    Reactions: Done → Queue."""
    return _schema(id, MoveTo(goal, speed), [Reaction(Done(), Queue())], watchdog_ms)


def move_to_touch(
    id: int,
    direction: Sequence[int],
    speed: int = 5_000,
    contact: int = 3_000,
    distance: int = 50_000,
    *,
    watchdog_ms: int = 0,
) -> Schema:
    """``moveToTouch(dir)``: along `direction` at `speed` µm/s (5 mm/s) until the contact force
    reaches `contact` mN (3 N; then the next queued schema), at most `distance` µm (50 mm; then
    the wait for the high-priority channel: nothing was there).
    Reactions: Above(Contact, contact) → Queue, Done → HighPriority."""
    return _schema(
        id,
        MoveToTouch(direction, speed, distance),
        [Reaction(Above(Contact(), contact), Queue()), Reaction(Done(), HighPriority())],
        watchdog_ms,
    )


def grasp(id: int, settle_ms: int = 200, *, watchdog_ms: int = 0) -> Schema:
    """``grasp()``: close the gripper and let it settle `settle_ms` (200 ms).
    Reactions: Done → Queue."""
    return _schema(id, Grasp(settle_ms), [Reaction(Done(), Queue())], watchdog_ms)


def release(id: int, settle_ms: int = 200, *, watchdog_ms: int = 0) -> Schema:
    """``release()``: open the gripper and let it settle `settle_ms` (200 ms).
    Reactions: Done → Queue."""
    return _schema(id, Release(settle_ms), [Reaction(Done(), Queue())], watchdog_ms)


def blind_search(
    id: int,
    preload: int = 2_000,
    pitch: int = 80,
    speed: int = 2_000,
    radius: int = 1_000,
    wobble: int = 20_000,
    wobble_ms: int = 500,
    depth: int = 1_000,
    *,
    watchdog_ms: int = 0,
) -> Schema:
    """``blind_search()``: press `preload` µm (2 mm) into the surface and spiral at `pitch` µm
    (0.08 mm) and `speed` µm/s (2 mm/s) over a square of half-width `radius` µm (1 mm), rocking
    ±`wobble` µrad (20 mrad) with period `wobble_ms` (500 ms), until the measured z has dropped
    `depth` µm (1 mm) below where it started; then the next queued schema.
    Reactions: Below(Displacement(2), -depth) → Queue (depth saturates at 2^31 - 1)."""
    _int(depth, 0, U32_MAX, "depth")
    return _schema(
        id,
        BlindSearch(preload, pitch, speed, radius, wobble, wobble_ms),
        [Reaction(Below(Displacement(2), -min(depth, I32_MAX)), Queue())],
        watchdog_ms,
    )


def idle(id: int, ms: int = 0, *, watchdog_ms: int = 0) -> Schema:
    """``idle(ms)``: hold the command for `ms` (0: until an event: for ever, unless aborted);
    then the next queued schema. Reactions: Done → Queue."""
    return _schema(id, Idle(ms), [Reaction(Done(), Queue())], watchdog_ms)


def atomic(id: int, action: Action, *, watchdog_ms: int = 0) -> Schema:
    """An atomic action (gripper, impedance, relieve), then the next queued schema at once.
    Reactions: OneShot → Queue."""
    return _schema(id, action, [Reaction(OneShot(), Queue())], watchdog_ms)


def gripper(id: int, g: Gripper, *, watchdog_ms: int = 0) -> Schema:
    """Open or close the gripper at once (no settling time: see :func:`grasp`)."""
    return atomic(id, _GripperAction(g), watchdog_ms=watchdog_ms)


def open_gripper(id: int, *, watchdog_ms: int = 0) -> Schema:
    """The network file's ``open()``: :func:`gripper` with ``Gripper.Open``."""
    return gripper(id, Gripper.Open, watchdog_ms=watchdog_ms)


def close_gripper(id: int, *, watchdog_ms: int = 0) -> Schema:
    """The network file's ``close()``: :func:`gripper` with ``Gripper.Closed``."""
    return gripper(id, Gripper.Closed, watchdog_ms=watchdog_ms)


def relieve(id: int, *, watchdog_ms: int = 0) -> Schema:
    """``relieve()``: the attractor to the measured pose (forces relieved), then the queue."""
    return atomic(id, Relieve(), watchdog_ms=watchdog_ms)


def set_impedance(
    id: int, stiffness: int = 2_000, damping: int = 100, *, watchdog_ms: int = 0
) -> Schema:
    """``set_impedance()``: the drive's stiffness N/m (2000) and damping N·s/m (100), then the
    queue."""
    return atomic(id, SetImpedance(stiffness, damping), watchdog_ms=watchdog_ms)


#: The builders by name, as the golden vectors name them.
BUILDERS = {
    f.__name__: f
    for f in (
        move_to,
        move_to_touch,
        grasp,
        release,
        blind_search,
        idle,
        gripper,
        open_gripper,
        close_gripper,
        relieve,
        set_impedance,
    )
}

__all__ = [
    "AXES",
    "MAX_REACTIONS",
    "QUEUE_DEPTH",
    "MAX_SENSORS",
    "MAX_COORD",
    "MAX_ENCODED",
    "BUILTIN_IDS",
    "WAIT_QUEUE",
    "WAIT_HIGH_PRIORITY",
    "SAFETY",
    "DecodeError",
    "Gripper",
    "Measure",
    "Event",
    "Source",
    "Action",
    "Reaction",
    "Schema",
    "MAX_JOINTS",
    "Joint",
    "Limits",
    "mm",
    "newtons",
    "mrad",
    "pose_mm",
    "BUILDERS",
    *BUILDERS,
    "atomic",
]
