"""pab_client.schema against the Rust builders and pab_core's Limits (golden_schemas.json,
written and checked by lang/tests/client_golden.rs), and the encodings' own properties."""

import json
import pathlib
import random

import pytest

from pab_client import schema as s
from pab_client.protocol import SchemaOutcome

GOLDEN = json.loads((pathlib.Path(__file__).parent / "golden_schemas.json").read_text())
VECTORS = GOLDEN["vectors"]
LIMITS_TABLE = s.Limits.from_json(GOLDEN["limits"]["table"])
LIMITS = GOLDEN["limits"]["vectors"]


def build(vector):
    if vector["call"] == "schema":
        return s.Schema.from_json(vector["schema"])
    return s.BUILDERS[vector["call"]](**vector["args"])


@pytest.mark.parametrize(
    "vector", VECTORS, ids=[f"{i}-{v['call']}" for i, v in enumerate(VECTORS)]
)
def test_the_python_builders_make_the_rust_builders_bytes(vector):
    schema = build(vector)
    assert schema.encode().hex() == vector["hex"]
    # The same structure as serde_json shows the Rust value, both ways.
    assert schema.to_json() == vector["schema"]
    assert s.Schema.from_json(vector["schema"]) == schema
    # Decoding gives it back; the check answers what the board's does.
    assert s.Schema.decode(bytes.fromhex(vector["hex"])) == schema
    check = schema.check()
    assert (None if check is None else check.name) == vector["check"]


def test_the_golden_file_covers_every_builder():
    assert {v["call"] for v in VECTORS} == set(s.BUILDERS) | {"schema"}


def test_unit_helpers_round_as_the_network_file_does():
    assert s.mm(20) == 20_000
    assert s.mm(-99.7) == -99_700
    assert s.mm(0.0005) == 1  # half away from zero, not to even
    assert s.mm(-0.0005) == -1
    assert s.mm(0.0025) == 3
    assert s.newtons(3) == 3_000
    assert s.mrad(20) == 20_000
    assert s.pose_mm(-100, -60, 35) == (-100_000, -60_000, 35_000, 0, 0, 0)
    assert s.pose_mm(1, 2, 3, 4, 5, 6) == (1000, 2000, 3000, 4000, 5000, 6000)
    with pytest.raises(ValueError):
        s.mm(float("nan"))


def test_three_values_are_a_translation():
    assert s.move_to(1, (1, 2, 3)) == s.move_to(1, (1, 2, 3, 0, 0, 0))


def test_values_outside_their_type_are_refused_before_encoding():
    with pytest.raises(ValueError):
        s.move_to(1, (2**31, 0, 0))
    with pytest.raises(ValueError):
        s.move_to(1, (0, 0, 0), speed=-1)
    with pytest.raises(ValueError):
        s.idle(0x10000)
    with pytest.raises(ValueError):
        s.grasp(1, settle_ms=2**32)
    with pytest.raises(TypeError):
        s.move_to(1, (1.5, 0, 0))  # µm are integers: mm() converts
    with pytest.raises(TypeError):
        s.idle(1, ms=True)
    with pytest.raises(ValueError):
        s.move_to(1, (1, 2, 3, 4))
    with pytest.raises(ValueError):
        s.Schema(1, s.Action.Relieve(), [s.Reaction(s.Event.Done(), s.Source.Queue())] * 17)
    with pytest.raises(TypeError):
        s.Schema(1, s.Event.Done())


def test_decoding_refuses_what_the_board_refuses():
    good = s.move_to(5, (1, 2, 3)).encode()
    for cut in range(len(good)):
        with pytest.raises(s.DecodeError) as e:
            s.Schema.decode(good[:cut])
        assert e.value.outcome == SchemaOutcome.Malformed
    with pytest.raises(s.DecodeError) as e:
        s.Schema.decode(good + b"\x00")
    assert e.value.outcome == SchemaOutcome.TrailingBytes
    # An unknown action (index 9), gripper (2), event (6), source (3), measure (5).
    for bad in ("0109", "010102", "01030106", "0103010103", "0103010405"):
        with pytest.raises(s.DecodeError):
            s.Schema.decode(bytes.fromhex(bad))
    # Seventeen reactions.
    with pytest.raises(s.DecodeError):
        s.Schema.decode(bytes.fromhex("010311" + "0001" * 17 + "00"))
    # A u16 varint whose third byte goes beyond 16 bits; a u32 one whose fifth goes beyond 32.
    with pytest.raises(s.DecodeError):
        s.Schema.decode(bytes.fromhex("ffff04" + "0300" + "00"))
    with pytest.raises(s.DecodeError):
        s.Schema.decode(bytes.fromhex("0100ffffffff7f" + "00" + "00"))
    # The largest three-byte id postcard writes (0xFFFF) decodes.
    assert s.Schema.decode(bytes.fromhex("ffff03" + "0300" + "00")).id == 0xFFFF


def test_random_schemas_round_trip():
    rng = random.Random(15)
    measures = [
        lambda: s.Measure.Position(rng.randrange(6)),
        lambda: s.Measure.Displacement(rng.randrange(6)),
        lambda: s.Measure.Force(rng.randrange(6)),
        lambda: s.Measure.Contact(),
        lambda: s.Measure.Sensor(rng.randrange(8)),
    ]
    i32 = lambda: rng.choice([0, -1, 1, rng.randrange(-(2**31), 2**31)])  # noqa: E731
    u32 = lambda: rng.choice([0, 1, 127, 128, rng.randrange(2**32)])  # noqa: E731
    events = [
        lambda: s.Event.OneShot(),
        lambda: s.Event.Done(),
        lambda: s.Event.Elapsed(u32()),
        lambda: s.Event.QueueReady(),
        lambda: s.Event.Above(rng.choice(measures)(), i32()),
        lambda: s.Event.Below(rng.choice(measures)(), i32()),
    ]
    sources = [
        lambda: s.Source.Innate(rng.randrange(256)),
        lambda: s.Source.Queue(),
        lambda: s.Source.HighPriority(),
    ]
    pose = lambda: tuple(i32() for _ in range(6))  # noqa: E731
    actions = [
        lambda: s.Action.Idle(u32()),
        lambda: s.Action.Gripper(rng.choice(list(s.Gripper))),
        lambda: s.Action.SetImpedance(u32(), u32()),
        lambda: s.Action.Relieve(),
        lambda: s.Action.MoveTo(pose(), u32()),
        lambda: s.Action.MoveToTouch(pose(), u32(), u32()),
        lambda: s.Action.BlindSearch(*(u32() for _ in range(6))),
        lambda: s.Action.Grasp(u32()),
        lambda: s.Action.Release(u32()),
    ]
    for _ in range(500):
        schema = s.Schema(
            rng.randrange(0x10000),
            rng.choice(actions)(),
            [
                s.Reaction(rng.choice(events)(), rng.choice(sources)())
                for _ in range(rng.randrange(17))
            ],
            u32(),
        )
        data = schema.encode()
        assert s.Schema.decode(data) == schema
        assert s.Schema.from_json(schema.to_json()) == schema
        assert len(data) <= s.MAX_ENCODED


def test_variants_read_like_the_rust_enums():
    assert repr(s.Action.MoveTo((1, 2, 3), 4)) == (
        "Action.MoveTo(goal=(1, 2, 3, 0, 0, 0), speed=4)"
    )
    assert isinstance(s.Event.Above(s.Measure.Contact(), 3), s.Event)
    assert s.Action.Gripper(s.Gripper.Closed)._to_json() == {"Gripper": "Closed"}
    assert s.Event.Done() != s.Event.OneShot()
    assert s.Measure.Position(2) != s.Measure.Displacement(2)


@pytest.mark.parametrize("vector", LIMITS, ids=[f"limits-{i}" for i in range(len(LIMITS))])
def test_limits_encode_as_the_rust_limits_and_are_checked_as_the_board_checks_them(vector):
    limits = s.Limits.from_json(vector["limits"])
    assert limits.encode().hex() == vector["hex"]
    assert limits.to_json() == vector["limits"]
    assert s.Limits.decode(bytes.fromhex(vector["hex"])) == limits
    within = limits.check_within(LIMITS_TABLE)
    assert (None if within is None else within.name) == vector["within"]


def test_the_limits_vectors_take_some_and_refuse_some():
    answers = [v["within"] for v in LIMITS]
    assert None in answers and "Looser" in answers
    assert any(len(v["limits"]["joints"]) == s.MAX_JOINTS for v in LIMITS)


def test_the_default_limits_are_the_boards():
    limits = s.Limits()
    assert limits == s.Limits.from_json(LIMITS[0]["limits"])
    assert limits.check() is None
    assert limits.check_within(limits) is None


def test_limits_refuse_what_cannot_be_encoded():
    with pytest.raises(ValueError):
        s.Limits(workspace_min=(0, 0, 0))  # a corner is six values
    with pytest.raises(ValueError):
        s.Limits(force_limit=-1)
    with pytest.raises(ValueError):
        s.Limits(speed_limit=2**32)
    with pytest.raises(ValueError):
        s.Limits(joints=[s.Joint(i, 0, 1) for i in range(9)])
    with pytest.raises(ValueError):
        s.Joint(256, 0, 1)
    with pytest.raises(ValueError):
        s.Joint(0, -(2**31) - 1, 1)
    with pytest.raises(TypeError):
        s.Limits(joints=[(0, 0, 1, 0)])
    with pytest.raises(TypeError):
        s.Limits(contact_limit=1.5)


def test_limits_decoding_refuses_what_the_board_refuses():
    good = LIMITS_TABLE.encode()
    for cut in range(len(good)):
        with pytest.raises(s.DecodeError) as e:
            s.Limits.decode(good[:cut])
        assert e.value.outcome == SchemaOutcome.Malformed
    with pytest.raises(s.DecodeError) as e:
        s.Limits.decode(good + b"\x00")
    assert e.value.outcome == SchemaOutcome.TrailingBytes
    # Nine joints: more than a board bounds.
    nine = s.Limits().encode()[:-1] + bytes([9]) + bytes(4) * 9
    with pytest.raises(s.DecodeError) as e:
        s.Limits.decode(nine)
    assert e.value.outcome == SchemaOutcome.Malformed


def test_limits_tighten_and_come_back_but_never_loosen():
    table = s.Limits(speed_limit=250_000, joints=[s.Joint(2, -1000, 1000, 500)])
    tight = s.Limits(
        workspace_min=(-200_000,) + (-1_000_000,) * 5,
        workspace_max=(1_000_000,) * 2 + (300_000,) + (1_000_000,) * 3,
        force_limit=10_000,
        torque_limit=2_000,
        contact_limit=5_000,
        speed_limit=100_000,
        rate_limit=500_000,
        joints=[s.Joint(2, -500, 800, 100)],
    )
    assert tight.check_within(table) is None
    assert table.check_within(tight) == SchemaOutcome.Looser
    assert table.check_within(table) is None
    rng = random.Random(10)
    for _ in range(200):
        limits = s.Limits(
            tuple(rng.randrange(-(2**31), 2**31) for _ in range(6)),
            tuple(rng.randrange(-(2**31), 2**31) for _ in range(6)),
            *(rng.choice([0, 1, rng.randrange(2**32)]) for _ in range(5)),
            [
                s.Joint(rng.randrange(256), rng.randrange(-(2**31), 2**31),
                        rng.randrange(-(2**31), 2**31), rng.randrange(2**32))
                for _ in range(rng.randrange(9))
            ],
        )
        data = limits.encode()
        assert s.Limits.decode(data) == limits
        assert s.Limits.from_json(limits.to_json()) == limits
        assert len(data) + 1 <= 257
