"""pab_hil.protocol against the core's payload layouts (client/python/tests/golden_layouts.json,
written from pab_core::protocol::layout by lang/tests/client_golden.rs): every service's code and
priority, the value tables the harness names, and each decoder read field by field."""

from __future__ import annotations

import json
import pathlib
import re

import pytest

from pab_hil import protocol as p

GOLDEN = pathlib.Path(__file__).resolve().parents[2] / "client/python/tests/golden_layouts.json"
SERVICES = {s["name"]: s for s in json.loads(GOLDEN.read_text())["services"]}


def constant(name: str) -> str:
    """The module constant of a service: TableStatus -> TABLE_STATUS."""
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).upper()


def write(payload: bytearray, field: dict, raw: int) -> None:
    mask = (1 << field["bits"]) - 1
    value = int.from_bytes(payload, "little")
    value &= ~(mask << field["bit"])
    value |= (raw & mask) << field["bit"]
    payload[:] = value.to_bytes(len(payload), "little")


def sample(service: dict) -> "tuple[bytes, dict]":
    """A payload with a distinct value in every field (an enumerated one: its second value, or
    its first), reserved fields 0, and those values by field name."""
    payload = bytearray(service["length"])
    values = {}
    for i, field in enumerate(service["fields"]):
        if field["reserved"]:
            raw = 0
        elif field["values"]:
            raw = field["values"][min(1, len(field["values"]) - 1)][0]
        else:
            most = field["max"] if field["max"] is not None and field["scale"] == "Unit" else None
            raw = (0x9E3779B97F4A7C15 >> i) & ((1 << field["bits"]) - 1)
            if most is not None:
                raw %= most + 1
            raw = raw or 1
        write(payload, field, raw)
        values[field["name"]] = raw
    return bytes(payload), values


def test_every_service_has_its_code_and_priority():
    assert len(SERVICES) == len(p.PRIORITY)
    for name, service in SERVICES.items():
        code = getattr(p, constant(name))
        assert code == service["code"], name
        assert p.PRIORITY[code] == service["priority"], name


def test_the_named_values_are_the_cores():
    state = SERVICES["Heartbeat"]["fields"][0]
    assert p.NODE_STATES == {code: text for code, text in state["values"]}
    status = SERVICES["TransferStatus"]["fields"][0]
    assert sorted(p.TRANSFER_STATUS_CODES) == [code for code, _ in status["values"]]


# Each decoder's attribute for each field of the layout (a function of the raw value), and the
# fields the harness does not read, by name: a field the core adds fails until it is listed.
READS = {
    "Heartbeat": {
        "state": ("state", lambda raw: p.NODE_STATES[raw]),
        "uptime": ("uptime_s", int),
        "table_version": ("table_version", int),
    },
    "TableStatus": {
        "crc": ("crc", int),
        "image_len": ("length", int),
        "ports": ("ports", int),
        "stored": ("stored", bool),
        "diagnostic": ("streaming", bool),
        "keyed": None,
    },
    "Traffic": {"received": ("received", int), "delivered": ("delivered", int)},
    "Errors": {"discarded": ("discarded", int), "errors": ("errors", int)},
    "Diagnostic": {
        "port": ("port", int),
        "connection": ("connection", int),
        "active": ("active", bool),
        "resting": ("resting", bool),
        "delivering": ("delivering", bool),
        "end_of_round": ("end_of_round", bool),
        "sequence": ("sequence", int),
        "level": ("level", lambda raw: raw / 2**31),
    },
    "TransferStatus": {
        "status": ("status", lambda raw: p.TRANSFER_STATUS_CODES[raw]),
        "detail": ("detail", int),
        "running_version": ("version", int),
        "reserved": None,
    },
    "Fault": {
        "code": ("code", int),
        "count": ("occurrences", int),
        **{
            f"detail{i}": ("detail", lambda raw, i=i: raw, i)  # checked below, byte by byte
            for i in range(5)
        },
    },
}


@pytest.mark.parametrize("name", sorted(READS))
def test_each_decoder_reads_every_field_where_the_layout_puts_it(name):
    service = SERVICES[name]
    reads = READS[name]
    assert sorted(reads) == sorted(f["name"] for f in service["fields"]), "every field listed"
    payload, values = sample(service)
    decoded = p.DECODERS[service["code"]](payload)
    for field, read in reads.items():
        if read is None:
            continue
        attribute, convert, *byte = read
        got = getattr(decoded, attribute)
        if byte:
            got = got[byte[0]]
        assert got == convert(values[field]), f"{name}.{field}"


def test_the_diagnostic_switch_writes_the_layouts_fields():
    service = SERVICES["DiagnosticControl"]
    payload = p.diagnostic_control(150, 0x1234)
    assert len(payload) == service["length"]
    expected = bytearray(service["length"])
    rate, ports = service["fields"]
    assert (rate["name"], ports["name"], rate["max"]) == ("rate", "ports", 200)
    write(expected, rate, 150)
    write(expected, ports, 0x1234)
    assert payload == bytes(expected)
