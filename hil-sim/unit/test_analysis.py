"""pab_hil.analysis on hand-made logs: no bus, no QEMU."""

import can

from pab_hil import analysis


def frame(t: float, can_id: int, data: bytes) -> can.Message:
    return can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=False, data=data)


def test_gateway_latency_follows_the_timestamps_not_the_log_order():
    topic, gateway = 0x110, 0x200
    log = [
        frame(1.000, topic, b"\x01"),
        frame(1.002, gateway, b"\x01"),
        # The re-publication of b"\x02" was read before the frame it re-publishes, which the
        # kernel stamped 0.5 ms earlier.
        frame(2.0015, gateway, b"\x02"),
        frame(2.0010, topic, b"\x02"),
        # A payload nobody published.
        frame(3.0, gateway, b"\x03"),
    ]
    latency = analysis.gateway_latency(log, {topic}, gateway)
    assert latency.count == 2
    assert latency.unmatched == 1
    assert abs(latency.median_ms - 1.25) < 1e-6
    assert abs(latency.max_ms - 2.0) < 1e-6
