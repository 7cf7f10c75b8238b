"""pab_client: a Python client of the pab schema server (docs/schema-server.md).

- :mod:`pab_client.schema`: schemas (actions, events, sources, reactions), their postcard
  encoding, and the builders of `pab_core::schema::build` (``move_to``, ``grasp``, ...), byte for
  byte what the Rust builders make (``tests/golden_schemas.json``); and the board's safety
  bounds, ``Limits``, which ``Client.set_limits`` tightens at run time;
- :mod:`pab_client.protocol`: the schema server's frames (docs/can-protocol.md);
- :mod:`pab_client.client`: :class:`Client`, which sends schemas to a node over ISO-TP on a
  python-can bus and follows its answers, transitions and state.

Units are the board's integers: µm and µrad, µm/s, mN, ms (``mm()``, ``newtons()``, ``mrad()``
and ``pose_mm()`` convert from the network file's mm, N and mrad).
"""

from .client import (
    FIRST_ID,
    LAST_ID,
    MAX_SECONDS,
    Client,
    ClientError,
    Denied,
    Ended,
    InvalidArgument,
    Refused,
    Timeout,
    client_filters,
)
from .protocol import (
    AuthFailure,
    Fault,
    FaultCode,
    SchemaAck,
    SchemaChannel,
    SchemaOrigin,
    SchemaOutcome,
    SchemaSafety,
    SchemaState,
    SchemaTransition,
    SchemaTrigger,
)
from .schema import (
    Action,
    Event,
    Gripper,
    Joint,
    Limits,
    Measure,
    Reaction,
    Schema,
    Source,
    blind_search,
    close_gripper,
    grasp,
    gripper,
    idle,
    mm,
    move_to,
    move_to_touch,
    mrad,
    newtons,
    open_gripper,
    pose_mm,
    release,
    relieve,
    set_impedance,
)

__all__ = [
    "Client",
    "client_filters",
    "ClientError",
    "Denied",
    "AuthFailure",
    "Fault",
    "FaultCode",
    "InvalidArgument",
    "MAX_SECONDS",
    "Refused",
    "Timeout",
    "Ended",
    "FIRST_ID",
    "LAST_ID",
    "SchemaAck",
    "SchemaChannel",
    "SchemaOrigin",
    "SchemaOutcome",
    "SchemaSafety",
    "SchemaState",
    "SchemaTransition",
    "SchemaTrigger",
    "Action",
    "Event",
    "Gripper",
    "Joint",
    "Limits",
    "Measure",
    "Reaction",
    "Schema",
    "Source",
    "blind_search",
    "close_gripper",
    "grasp",
    "gripper",
    "idle",
    "mm",
    "move_to",
    "move_to_touch",
    "mrad",
    "newtons",
    "open_gripper",
    "pose_mm",
    "release",
    "relieve",
    "set_impedance",
]
