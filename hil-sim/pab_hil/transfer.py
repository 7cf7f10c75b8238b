"""Table transfers by a third-party ISO-TP stack (python can-isotp), beside `pabctl push`.

The tests use it to put bytes on the wire that pabctl would never send (a corrupted image), and
in doing so check our nodes' ISO-TP receiver against an independent implementation of ISO 15765-2.
"""

from __future__ import annotations

import can
import isotp

from . import protocol as p


def send_image(iface: str, node_id: int, image: bytes, timeout: float = 10.0) -> None:
    """Sends `image` to `node_id` as one ISO-TP message on the TableTransfer service (29-bit ids,
    frames padded to 8 bytes as our protocol asks). Returns when the last frame is sent; the node's
    verdict comes separately, as a TransferStatus frame."""
    address = isotp.Address(
        isotp.AddressingMode.Normal_29bits,
        txid=p.frame_id(p.TABLE_TRANSFER, p.TOOL, node_id),
        rxid=p.frame_id(p.TABLE_TRANSFER, node_id, p.TOOL),
    )
    # Only the node's flow control: the stack's thread must not wade through the whole bus.
    bus = can.Bus(
        interface="socketcan",
        channel=iface,
        can_filters=[{"can_id": address.get_rx_arbitration_id(), "can_mask": 0x1FFFFFFF,
                      "extended": True}],
    )
    stack = isotp.CanStack(
        bus,
        address=address,
        params={"tx_padding": 0, "tx_data_min_length": 8, "blocking_send": True},
    )
    try:
        stack.start()
        stack.send(image, send_timeout=timeout)
    finally:
        stack.stop()
        bus.shutdown()
