"""The cangw filters of the emulated board's routes (pab_hil.board.acceptance), evaluated as cangw
evaluates them: what reaches the board, and that nothing reaches it twice."""

from __future__ import annotations

import pytest

from pab_hil import protocol as p, team
from pab_hil.board import acceptance

EFF = 0x8000_0000  # CAN_EFF_FLAG: cangw compares it with the identifier
BOARD = 10


def passes(route: str, can_id: int) -> bool:
    """cangw's -f: `id:mask` passes when id & mask match, `id~mask` when they differ."""
    if "~" in route:
        ident, mask = (int(x, 16) for x in route.split("~"))
        return can_id & mask != ident & mask
    ident, mask = (int(x, 16) for x in route.split(":"))
    return can_id & mask == ident & mask


def routes_passing(can_id: int, routes=None) -> int:
    return sum(passes(r, can_id) for r in (routes or acceptance(BOARD)))


def ours(service: int, source: int = 3, destination: int = p.BROADCAST) -> int:
    """One of our frames, at any priority (services without one of their own too)."""
    return EFF | p.PROTOCOL_VALUE | service << 16 | destination << 8 | source


def test_the_emergency_stop_reaches_the_board_once_broadcast_or_addressed():
    for destination in (p.BROADCAST, BOARD):
        assert routes_passing(ours(p.EMERGENCY_STOP, 0, destination)) == 1
    assert routes_passing(ours(p.EMERGENCY_STOP, 0, 3)) == 0  # to another node


def test_the_reports_do_not_reach_the_board():
    for service in (p.FAULT, p.HEARTBEAT, p.TABLE_STATUS, p.TRAFFIC, p.ERRORS, p.DIAGNOSTIC):
        assert routes_passing(ours(service)) == 0, hex(service)
    # Answers to the tool, the board's own included.
    for service in (p.TRANSFER_STATUS, p.TABLE_TRANSFER, p.CHALLENGE, p.SCHEMA_ACK):
        assert routes_passing(ours(service, BOARD, p.TOOL)) == 0, hex(service)


def test_another_nodes_commands_and_transfers_do_not_reach_the_board():
    for service in (p.TABLE_TRANSFER, p.TRANSFER_OPEN, p.SCHEMA_TRANSFER, p.FILTER_SET,
                    p.DIAGNOSTIC_CONTROL):
        assert routes_passing(ours(service, p.TOOL, 3)) == 0, hex(service)


def test_commands_transfers_broadcasts_claims_and_topics_reach_the_board_once():
    addressed = [ours(s, p.TOOL, BOARD) for s in range(0x00, 0x80)]
    broadcast = [ours(s, 3, p.BROADCAST) for s in (0x00, p.GATES, *range(0x08, 0x80))]
    claims = [EFF | p.Claim(group, node, eligibility).arbitration_id()
              for node in (1, BOARD, 127) for group in (0, 5) for eligibility in (0, 1, 0xFFFF)]
    topics = [0x000, 0x123, 0x7FF, EFF | 0x0000_0100, EFF | 0x1FFF_FFFF, EFF | 0x0100_0000]
    for can_id in addressed + broadcast + claims + topics:
        assert routes_passing(can_id) == 1, hex(can_id)


def test_a_robots_board_takes_only_its_own_behaviours_topics():
    routes = team.board_routes(1)
    for can_id in (team.observer_id(1, t) for t in team.TARGETS):
        assert routes_passing(can_id, routes) == 1
    assert routes_passing(team.wander_id(1), routes) == 1
    for can_id in (team.observer_id(2, 1), team.wander_id(3), team.drive_id(1)):
        assert routes_passing(can_id, routes) == 0, hex(can_id)
    # The protocol's part is the board's acceptance filter.
    assert routes_passing(ours(p.TABLE_TRANSFER, p.TOOL, 1), routes) == 1
    assert routes_passing(ours(p.TABLE_TRANSFER, p.TOOL, 2), routes) == 0


def test_node_ids_outside_the_protocol_are_refused():
    for node in (0, 128):
        with pytest.raises(ValueError):
            acceptance(node)
