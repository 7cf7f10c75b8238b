"""Table transfers by a third-party ISO-TP implementation, beside `pabctl push`: the Linux
kernel's own (module can-isotp), through python can-isotp's socket wrapper.

The tests use it to put bytes on the wire that pabctl would never send (a corrupted image), and
in doing so check our nodes' ISO-TP receiver against an independent implementation of ISO 15765-2.
The kernel's, not can-isotp's Python stack: the kernel answers the node's flow control itself,
where a Python thread in the harness's busy process, under software emulation, once sent the
consecutive frames so late that the node's transfer timed out.
"""

from __future__ import annotations

import isotp

from . import protocol as p


class TransferError(RuntimeError):
    pass


def send_image(iface: str, node_id: int, image: bytes, timeout: float = 10.0) -> None:
    """Sends `image` to `node_id` as one ISO-TP message on the TableTransfer service (29-bit ids,
    frames padded to 8 bytes as our protocol asks). Returns when the last frame is sent; the node's
    verdict comes separately, as a TransferStatus frame."""
    address = isotp.Address(
        isotp.AddressingMode.Normal_29bits,
        txid=p.frame_id(p.TABLE_TRANSFER, p.TOOL, node_id),
        rxid=p.frame_id(p.TABLE_TRANSFER, node_id, p.TOOL),
    )
    try:
        sock = isotp.socket(timeout=timeout)
    except OSError as error:
        raise TransferError(f"no ISO-TP socket ({error}): the kernel's can-isotp module is "
                            "needed (modprobe can-isotp)") from error
    try:
        # Padded to 8 bytes with 0; send() returns once the last frame is out (or fails: no flow
        # control, the node's overflow).
        sock.set_opts(optflag=isotp.socket.flags.TX_PADDING | isotp.socket.flags.WAIT_TX_DONE,
                      txpad=0x00)
        sock.bind(iface, address)
        sock.send(image)
    except OSError as error:
        raise TransferError(f"the kernel's ISO-TP transfer to node {node_id} failed: {error}") \
            from error
    finally:
        sock.close()
