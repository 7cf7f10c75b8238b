"""The cangw filters of the emulated board's routes (pab_hil.board.TO_BOARD), evaluated as cangw
evaluates them: what reaches the board, and that nothing reaches it twice."""

from __future__ import annotations

from pab_hil import protocol as p
from pab_hil.board import ESTOP_FILTER, ROUTE_FILTER, TO_BOARD

EFF = 0x8000_0000  # CAN_EFF_FLAG: cangw compares it with the identifier


def passes(route: str, can_id: int) -> bool:
    """cangw's -f: `id:mask` passes when id & mask match, `id~mask` when they differ."""
    if "~" in route:
        ident, mask = (int(x, 16) for x in route.split("~"))
        return can_id & mask != ident & mask
    ident, mask = (int(x, 16) for x in route.split(":"))
    return can_id & mask == ident & mask


def routes_passing(can_id: int) -> int:
    return sum(passes(r, can_id) for r in TO_BOARD)


def ours(service: int, source: int = 10, destination: int = p.BROADCAST) -> int:
    return EFF | p.frame_id(service, source, destination)


def test_the_emergency_stop_reaches_the_board_once_broadcast_or_addressed():
    assert ESTOP_FILTER in TO_BOARD and ROUTE_FILTER in TO_BOARD
    for destination in (p.BROADCAST, 3, 10):
        assert routes_passing(ours(p.EMERGENCY_STOP, 0, destination)) == 1


def test_the_reports_to_the_tool_do_not_reach_the_board():
    for service in (p.FAULT, p.HEARTBEAT, 0x03, 0x07):
        assert routes_passing(ours(service)) == 0, hex(service)


def test_commands_transfers_and_topics_reach_the_board_once():
    commands = [ours(s, 0, 10) for s in (p.TABLE_TRANSFER, p.SCHEMA_ABORT, p.SCHEMA_TRANSFER)]
    topics = [0x000, 0x123, 0x7FF, EFF | 0x0000_0100, EFF | 0x1FFF_FFFF]
    for can_id in commands + topics:
        assert routes_passing(can_id) == 1, hex(can_id)
