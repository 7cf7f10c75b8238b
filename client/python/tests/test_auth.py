"""pab_client.auth against the core's tags and MACs (golden_auth.json, written and checked by
lang/tests/client_golden.rs), and the key file's rules."""

import json
import pathlib

import pytest

from pab_client import auth

GOLDEN = json.loads((pathlib.Path(__file__).parent / "golden_auth.json").read_text())


def test_the_tags_and_macs_are_the_cores():
    key = bytes.fromhex(GOLDEN["key"])
    assert len(GOLDEN["vectors"]) == 2
    for v in GOLDEN["vectors"]:
        node, nonce, message = v["node"], int(v["nonce"]), bytes.fromhex(v["message"])
        exchange = auth.exchange(key, node, int(v["tool_nonce"]), int(v["node_nonce"]))
        assert exchange == (nonce, bytes.fromhex(v["binding"]))
        assert v["length"] == len(message) + auth.IMAGE_MAC_LEN
        assert auth.open_tag(key, node, nonce, v["length"], auth.OPEN_SCHEMA).hex() == v["open_tag"]
        assert auth.image_mac(key, node, nonce, auth.OPEN_SCHEMA, message).hex() == v["image_mac"]
        tag = auth.receipt_tag(key, node, nonce, bytes.fromhex(v["ack"]), 0, False)
        assert tag.hex() == v["receipt_tag"]


def test_rfc_4493_example_2():
    # AES-128-CMAC of one block (RFC 4493, section 4, example 2).
    key = bytes.fromhex("2b7e151628aed2a6abf7158809cf4f3c")
    mac = auth.cmac(key, bytes.fromhex("6bc1bee22e409f96e93d7e117393172a"))
    assert mac.hex() == "070a16b46b4d4144f79bdd9dd04a287c"


def test_key_files(tmp_path):
    path = tmp_path / "node.key"
    path.write_text("00112233445566778899aabbccddeeff\n")
    path.chmod(0o600)
    assert auth.read_key(path) == bytes.fromhex("00112233445566778899aabbccddeeff")
    path.write_text("0011\n")
    with pytest.raises(auth.KeyFileError, match="32 hexadecimal"):
        auth.read_key(path)
    path.write_text("zz" * 16)
    with pytest.raises(ValueError):
        auth.read_key(path)
    # A key of zeros is a placeholder; a key others may read is no key; a device is no file.
    path.write_text("0" * 32 + "\n")
    with pytest.raises(auth.KeyFileError, match="all zeros"):
        auth.read_key(path)
    path.write_text("00112233445566778899aabbccddeeff\n")
    path.chmod(0o644)
    with pytest.raises(auth.KeyFileError, match="mode 0644 lets other users read the key"):
        auth.read_key(path)
    with pytest.raises(auth.KeyFileError, match="not a key file"):
        auth.read_key("/dev/zero")


def test_tool_nonces_are_64_random_bits():
    nonces = {auth.new_tool_nonce() for _ in range(64)}
    assert len(nonces) == 64
    assert all(0 <= n < 1 << 64 for n in nonces)
