"""Authenticated schema transfers to a node with a key (docs/can-protocol.md, "Authenticated
configuration"): AES-128-CMAC tags as `pab_core::auth::Authenticator` makes them, every MAC input
starting with its domain byte and the node id.

    key = read_key("arm.key")                     # pabctl keygen's file: 32 hex characters
    tool_nonce = new_tool_nonce()                 # in the ChallengeRequest
    nonce, binding = exchange(key, node, tool_nonce, node_nonce)   # from the node's Challenge
    open_tag(key, node, nonce, length, OPEN_SCHEMA)
    image_mac(key, node, nonce, OPEN_SCHEMA, message)
    receipt_tag(key, node, nonce, schema_ack_payload, 0, False)

The CMAC is the `cryptography` package's (OpenSSL's).
"""

from __future__ import annotations

import os
import stat
import struct
from pathlib import Path

from cryptography.hazmat.primitives.ciphers import algorithms
from cryptography.hazmat.primitives.cmac import CMAC

#: Domains (the first byte of every MAC input).
COMMAND, OPEN, IMAGE, RECEIPT, EXCHANGE, NODE_NONCE = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
#: TransferOpen flags: a table version reset; a schema message (not a table image).
OPEN_REPLACE = 0x01
OPEN_SCHEMA = 0x02
#: Lengths of the tags and MACs.
OPEN_TAG_LEN, IMAGE_MAC_LEN, RECEIPT_TAG_LEN = 5, 16, 8
#: A node nonce's bytes on the wire (48 bits), and a Challenge's binding.
NODE_NONCE_LEN, BINDING_LEN = 6, 2


class KeyFileError(ValueError):
    """A key file that is refused: not a regular file, readable by others, malformed, or a key
    of zeros (a placeholder)."""


def read_key(path: "str | Path") -> bytes:
    """A key file's 16 bytes: 32 hexadecimal characters, optionally one newline after them. As
    pabctl's: a regular file of at most 256 bytes, readable by its owner only, not all zeros;
    :class:`KeyFileError` otherwise."""
    path = Path(path)
    try:
        info = path.stat()
    except OSError as error:
        raise KeyFileError(f"{path}: cannot read the key file: {error.strerror}") from None
    if not stat.S_ISREG(info.st_mode) or info.st_size > 256:
        raise KeyFileError(f"{path}: not a key file (a regular file of 32 hexadecimal characters)")
    if info.st_mode & 0o077:
        raise KeyFileError(
            f"{path}: mode {info.st_mode & 0o7777:04o} lets other users read the key: chmod 600 {path}"
        )
    text = path.read_text()
    if text.endswith("\n"):
        text = text[:-1].removesuffix("\r")
    if len(text) != 32:
        raise KeyFileError(f"{path}: a key is 32 hexadecimal characters (128 bits), this has {len(text)}")
    try:
        key = bytes.fromhex(text)
    except ValueError:
        raise KeyFileError(f"{path}: a key is 32 of 0-9, a-f") from None
    if key == bytes(16):
        raise KeyFileError(f"{path}: the key is all zeros, a placeholder rather than a secret")
    return key


def cmac(key: bytes, *parts: bytes) -> bytes:
    """AES-128-CMAC of the parts, concatenated (16 bytes)."""
    if len(key) != 16:
        raise ValueError(f"a key is 16 bytes, not {len(key)}")
    mac = CMAC(algorithms.AES(key))
    for part in parts:
        mac.update(part)
    return mac.finalize()


def new_tool_nonce() -> int:
    """A tool nonce: 64 random bits from the operating system, new for every exchange."""
    return int.from_bytes(os.urandom(8), "little")


def exchange(key: bytes, node: int, tool_nonce: int, node_nonce: int) -> "tuple[int, bytes]":
    """The exchange of a ChallengeRequest's tool nonce and the Challenge's node nonce: the nonce
    every tag of the exchange is over (CMAC(0x05, node, tool nonce, node nonce) bytes 0-7) and
    the binding the Challenge must carry (bytes 8-9) to answer this request."""
    full = cmac(key, bytes([EXCHANGE, node]), struct.pack("<Q", tool_nonce),
                (node_nonce & (1 << 48) - 1).to_bytes(NODE_NONCE_LEN, "little"))
    return int.from_bytes(full[:8], "little"), full[8:8 + BINDING_LEN]


def open_tag(key: bytes, node: int, nonce: int, length: int, flags: int) -> bytes:
    """A TransferOpen's tag: CMAC(0x02, node, nonce, length, flags), its first 5 bytes."""
    return cmac(key, bytes([OPEN, node]), struct.pack("<QHB", nonce, length, flags))[:OPEN_TAG_LEN]


def image_mac(key: bytes, node: int, nonce: int, flags: int, message: bytes) -> bytes:
    """The MAC after an opened transfer's message: CMAC(0x03, node, nonce, flags, message)."""
    return cmac(key, bytes([IMAGE, node]), struct.pack("<QB", nonce, flags), bytes(message))


def receipt_tag(key: bytes, node: int, nonce: int, answer: bytes, running_crc: int,
                stored: bool) -> bytes:
    """A Receipt's tag: CMAC(0x04, node, nonce, the answer's 8 bytes, CRC, stored), 8 bytes. For
    a schema the answer is the SchemaAck's payload, the CRC and the stored flag 0."""
    return cmac(key, bytes([RECEIPT, node]), struct.pack("<Q", nonce), bytes(answer),
                struct.pack("<IB", running_crc, int(stored)))[:RECEIPT_TAG_LEN]
