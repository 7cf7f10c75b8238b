"""ISO-TP on CAN FD as python can-isotp segments it: the golden frames core/tests/isotp_fd.rs
checks pab-core's `isotp::fd` encoders and decoder against.

    target/venv/bin/python scripts/isotp_fd_golden.py > core/tests/fixtures/isotp_fd_can_isotp.txt

can-isotp's TransportLayerLogic, without a bus: its txfn keeps each frame, its rxfn hands it a
Flow Control (continue, block size 0, STmin 0) after the First Frame. Parameters as pab-core's
module decides: CAN FD, TX_DL each of the eight, padding 0xCC, frames padded to 8 bytes at least
(`tx_data_min_length = 8`). One line per message: `TX_DL LEN COUNT FRAME FRAME ...`, each frame
in hex, COUNT frames; a message of more than 4000 bytes lists its first two frames, `...` and its
last (the Consecutive Frames between follow from them). The message's byte i is
(i * 7 + LEN) & 0xFF. ./test.sh checks that this still writes the committed file.
"""

import sys

import isotp

TX_DLS = (8, 12, 16, 20, 24, 32, 48, 64)
# Every length a Single Frame, the First Frame or the first Consecutive Frames can end at (at
# TX_DL 64: 62, 125, and into a second Consecutive Frame), then the escape's edge.
LENGTHS = tuple(range(1, 131)) + (4095, 4096, 5000)


class _Message:
    def __init__(self, data: bytes) -> None:
        self.arbitration_id = 0x7E8
        self.data = data
        self.dlc = 8
        self.is_extended_id = False
        self.is_fd = True
        self.bitrate_switch = False


def message(length: int) -> bytes:
    return bytes((i * 7 + length) & 0xFF for i in range(length))


def frames(tx_dl: int, payload: bytes) -> list[bytes]:
    sent: list[bytes] = []
    pending: list[isotp.CanMessage] = []

    def txfn(msg: isotp.CanMessage) -> None:
        sent.append(bytes(msg.data))
        if msg.data[0] >> 4 == 1:  # a First Frame: answer it
            pending.append(isotp.CanMessage(arbitration_id=0x7E0, data=bytes([0x30, 0, 0]),
                                            is_fd=True))

    def rxfn(timeout: float) -> isotp.CanMessage | None:
        return pending.pop(0) if pending else None

    layer = isotp.TransportLayerLogic(
        rxfn=rxfn, txfn=txfn,
        address=isotp.Address(isotp.AddressingMode.Normal_11bits, txid=0x7E8, rxid=0x7E0),
        params={"can_fd": True, "tx_data_length": tx_dl, "tx_data_min_length": 8,
                "tx_padding": 0xCC, "blocking_send": False})
    layer.send(payload)
    for _ in range(100_000):
        layer.process()
        if not layer.transmitting() and not pending:
            break
    else:
        raise RuntimeError(f"can-isotp did not finish sending {len(payload)} bytes at {tx_dl}")
    return sent


def main() -> None:
    out = sys.stdout
    out.write(f"# python can-isotp {isotp.__version__}: scripts/isotp_fd_golden.py\n")
    for tx_dl in TX_DLS:
        for length in LENGTHS:
            sent = frames(tx_dl, message(length))
            shown = [f.hex() for f in sent]
            if length > 4000:
                shown = shown[:2] + ["..."] + shown[-1:]
            out.write(f"{tx_dl} {length} {len(sent)} {' '.join(shown)}\n")


if __name__ == "__main__":
    main()
