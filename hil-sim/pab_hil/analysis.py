"""Figures from a candump log: what the bus itself shows, by kernel timestamps."""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from pathlib import Path

import can

from . import protocol as p


@dataclass(frozen=True)
class Latency:
    """Behaviour frame -> the node's re-published frame with the same payload."""

    count: int
    unmatched: int  # re-published frames whose payload no topic frame carried before
    median_ms: float
    p99_ms: float
    max_ms: float


def read_log(path: Path) -> list[can.Message]:
    return list(can.CanutilsLogReader(str(path)))


def gateway_latency(messages: list[can.Message], topics: set[int], gateway_id: int) -> Latency:
    """For each frame on `gateway_id`, the delay since the latest frame on one of `topics` with the
    same payload (payloads carry a publisher id and sequence number, so they match one frame).

    In the order of the kernel's timestamps, not of the log's lines: the recorder reads frames from
    several senders as the micro-VM's CPUs hand them over, and a behaviour's frame stamped before
    the gateway re-published it can come after it in the log (seen once: 0.5 ms apart)."""
    last_seen: dict[bytes, float] = {}
    delays: list[float] = []
    unmatched = 0
    for message in sorted(messages, key=lambda m: m.timestamp):
        if message.is_extended_id:
            continue
        data = bytes(message.data)
        if message.arbitration_id in topics:
            last_seen[data] = message.timestamp
        elif message.arbitration_id == gateway_id:
            published = last_seen.get(data)
            if published is None:
                unmatched += 1
            else:
                delays.append((message.timestamp - published) * 1000.0)
    if not delays:
        return Latency(0, unmatched, float("nan"), float("nan"), float("nan"))
    delays.sort()
    p99 = delays[min(len(delays) - 1, round(0.99 * (len(delays) - 1)))]
    return Latency(len(delays), unmatched, statistics.median(delays), p99, delays[-1])


def faults(messages: list[can.Message], node_id: int) -> list[tuple[float, p.Fault]]:
    """A node's fault frames in a candump log, with their kernel timestamps. The log is the
    ground truth: the recorder's socket has a buffer for minutes of a flood, where the harness's
    own listener (a Python thread that also drives the world) may fall behind."""
    fault_id = p.frame_id(p.FAULT, node_id, p.BROADCAST)
    return [(m.timestamp, p.Fault.decode(bytes(m.data))) for m in messages
            if m.is_extended_id and m.arbitration_id == fault_id]
