"""pab_client.protocol against the core's payload layouts (golden_layouts.json, written from
pab_core::protocol::layout by lang/tests/client_golden.rs): the services' codes and priorities,
and the schema server's reports encoded and decoded field by field where the layout puts them."""

import json
import pathlib
import re

import pytest

from pab_client import protocol as p
from pab_client.protocol import (
    SchemaAck,
    SchemaChannel,
    SchemaOrigin,
    SchemaOutcome,
    SchemaSafety,
    SchemaState,
    SchemaTransition,
    SchemaTrigger,
)

GOLDEN = pathlib.Path(__file__).parent / "golden_layouts.json"
SERVICES = {s["name"]: s for s in json.loads(GOLDEN.read_text())["services"]}


def read(payload: bytes, field: dict) -> int:
    return int.from_bytes(payload, "little") >> field["bit"] & ((1 << field["bits"]) - 1)


def test_the_services_the_client_names_have_the_cores_codes_and_priorities():
    named = 0
    for name, service in SERVICES.items():
        constant = re.sub(r"(?<!^)(?=[A-Z])", "_", name).upper()
        if not hasattr(p, constant):
            continue
        named += 1
        code = getattr(p, constant)
        assert code == service["code"], name
        assert p.PRIORITY[code] == service["priority"], name
    assert named == len(p.PRIORITY) == 11


# Each report, a value with every field distinct, and how its attributes read as the layout's
# raw fields (an optional code is 0xFF when None).
REPORTS = {
    "Fault": (
        p.Fault(p.FaultCode.Unauthenticated, 200, bytes([5, 0x13, 0x7E, 0x11, 0x22])),
        lambda r: {
            "code": int(r.code),
            "count": r.count,
            **{f"detail{i}": r.detail[i] for i in range(5)},
        },
    ),
    "SchemaAck": (
        SchemaAck(SchemaOutcome.QueueFull, SchemaChannel.HighPriority, 0x1234, 7, 45),
        lambda r: {
            "outcome": int(r.outcome),
            "channel": p.NO_CHANNEL if r.channel is None else int(r.channel),
            "id": r.id,
            "queued": r.queued,
            "stop": r.stop,
            "reserved": 0,
        },
    ),
    "SchemaTransition": (
        SchemaTransition(0x0102, 0xFF12, SchemaTrigger.Safety, SchemaSafety.Force, SchemaOrigin.Innate, 5),
        lambda r: {
            "ended": r.ended,
            "installed": r.installed,
            "trigger": int(r.trigger),
            "detail": r.detail,
            "source": int(r.source),
            "queued": r.queued,
        },
    ),
    "SchemaState": (
        SchemaState(0x0304, SchemaOrigin.Queue, SchemaSafety.Overrun, 3, True, False, 0xBEEF, 42),
        lambda r: {
            "current": r.current,
            "source": int(r.source),
            "fault": p.NO_FAULT if r.fault is None else int(r.fault),
            "queued": r.queued,
            "armed": int(r.armed),
            "gripper_closed": int(r.gripper_closed),
            "stop": r.stop,
            "elapsed": r.elapsed_ms,
        },
    ),
}


@pytest.mark.parametrize("name", sorted(REPORTS))
def test_each_report_is_the_layouts_fields(name):
    service = SERVICES[name]
    report, fields = REPORTS[name]
    expected = fields(report)
    assert sorted(expected) == sorted(f["name"] for f in service["fields"]), "every field"
    payload = report.encode()
    assert len(payload) == service["length"]
    assert {f["name"]: read(payload, f) for f in service["fields"]} == expected
    assert type(report).decode(payload) == report
