"""Held-out inputs to the content store and model bundles (second pass): CID text of any
length, manifests and envelopes nested past the JSON parser, sizes a manifest lies about,
and a sealed pull into a folder holding a planted file. Each test fails on the code before
its fix (its docstring says what happened then)."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from eth_account import Account

from backend.chain.pyevm import restore_recursion_limit
from backend.store import CID, EmbeddedStore, InvalidCID, InvalidContent
from backend.store.bundle import canonical_json, pull_model, read_bundle, upload_model
from backend.store.sealed import (
    parse_public_key,
    public_key_hex,
    pull_model_with_key,
    read_envelope,
    seal_model,
    sealed_envelopes,
)

REQUESTER = Account.from_key("0x" + "11" * 32)


@pytest.fixture(autouse=True)
def normal_recursion_limit() -> Iterator[None]:
    """The interpreter's usual limit, as the gateway and the CLI run with (eth_account's
    imports raise it to 100,000, past which deep JSON overflows the C stack instead)."""
    before = sys.getrecursionlimit()
    restore_recursion_limit()
    yield
    sys.setrecursionlimit(before)


def _manifest(store: EmbeddedStore, cid: str) -> dict:
    return json.loads(store.get(cid))


def test_cid_text_longer_than_any_cid_is_refused_before_it_is_decoded() -> None:
    """Base58 decoding is quadratic: 300 kB of ``z2222...`` (a task description any funded
    user can put on chain, which the indexer parses as a CID) took 17 s, and the error
    repeated the whole input. Now it is refused by its length, naming its first characters."""
    text = "z" + "2" * 100_000
    with pytest.raises(InvalidCID, match="longer than any CID") as caught:
        CID.parse(text)
    message = str(caught.value)
    assert "'z2222" in message and "100001 long" in message
    assert len(message) < 300
    cid = CID.for_block(b"x", 0x55)  # CIDs, the longest spelling of them too, still parse
    assert CID.parse(" " + str(cid) + "\n") == cid
    assert CID.parse("B" + str(cid)[1:].upper()) == cid


def test_a_manifest_declaring_more_bytes_than_its_file_has_is_refused(
    store: EmbeddedStore, model_dir: Path, tmp_path: Path
) -> None:
    """A manifest saying 5,000 bytes of a 3,000-byte weights file: `model pull` and `task
    pull` wrote it as it was (the worker's expert fetch refuses it). Now InvalidContent names
    the file and both sizes, and the file is not left behind."""
    files = read_bundle(store, upload_model(store, model_dir))
    entries = {n: {"cid": c, "size": size} for n, (c, size) in files.items()}
    entries["model.safetensors"]["size"] = 5000
    cid = store.add(canonical_json({"format": "drlaas-bundle/1", "files": entries}))
    for i, pull in enumerate((pull_model, lambda s, c, d: pull_model_with_key(s, c, d, None))):
        out = tmp_path / f"out{i}"
        with pytest.raises(InvalidContent, match="has 3000 bytes, its manifest says 5000"):
            pull(store, cid, out)
        assert not (out / "model.safetensors").exists()


def test_a_sealed_file_shorter_than_its_manifest_says_is_refused(
    store: EmbeddedStore, model_dir: Path, tmp_path: Path
) -> None:
    """The manifest and envelope of a sealed outcome both claiming 10 bytes more than the
    weights: the ciphertext was read within the claimed size, decrypted and matched its
    CID, and the shorter weights were written. Now the size is checked too."""
    cid = seal_model(store, model_dir, parse_public_key(public_key_hex(bytes(REQUESTER.key))))
    manifest = _manifest(store, cid)
    envelope = read_envelope(store, sealed_envelopes(store, cid)["model.safetensors"])
    manifest["files"]["model.safetensors"]["size"] += 10
    envelope["cipher_size"] += 10
    manifest["sealed"]["model.safetensors"] = store.add(canonical_json(envelope))
    forged = store.add(canonical_json(manifest))
    with pytest.raises(InvalidContent, match="has 3000 bytes, its manifest says 3010"):
        pull_model_with_key(store, forged, tmp_path / "out", bytes(REQUESTER.key))
    assert not (tmp_path / "out" / "model.safetensors").exists()


def test_a_manifest_nested_past_the_parser_is_not_a_bundle_for_sealed_envelopes(
    store: EmbeddedStore,
) -> None:
    """``sealed_envelopes`` parsed the manifest again without the guard of ``read_bundle``
    and raised RecursionError: the gateway's ``POST /models`` (which calls it first) answered
    500, `task pull --key` said "RecursionError". Now it is InvalidContent, a store error."""
    cid = store.add(b"[" * 30_000 + b"]" * 30_000)
    with pytest.raises(InvalidContent, match="not a JSON bundle manifest"):
        sealed_envelopes(store, cid)


def test_an_envelope_nested_past_the_parser_is_invalid_content(store: EmbeddedStore) -> None:
    """An envelope of 2,000 nested lists: ``read_envelope`` raised RecursionError."""
    cid = store.add(b"[" * 2000 + b"]" * 2000)
    with pytest.raises(InvalidContent, match="not a JSON envelope"):
        read_envelope(store, cid)


def test_a_boolean_size_in_a_manifest_is_a_bad_entry(
    store: EmbeddedStore, model_dir: Path
) -> None:
    """``"size": true`` passed as an int (1): a 1-byte file was read under it."""
    files = read_bundle(store, upload_model(store, model_dir))
    entries = {n: {"cid": c, "size": size} for n, (c, size) in files.items()}
    entries["model.json"]["size"] = True
    cid = store.add(canonical_json({"format": "drlaas-bundle/1", "files": entries}))
    with pytest.raises(InvalidContent, match="bad entry for 'model.json'"):
        read_bundle(store, cid)


def test_a_sealed_pull_writes_nothing_through_a_file_planted_in_the_folder(
    store: EmbeddedStore, model_dir: Path, tmp_path: Path
) -> None:
    """The decrypted weights went to ``.model.safetensors.part`` in the destination first,
    opened by that fixed name: a symlink there made the pull write the weights over the
    file it points to, outside the folder. Now a new temporary file is made each time."""
    cid = seal_model(store, model_dir, parse_public_key(public_key_hex(bytes(REQUESTER.key))))
    outside = tmp_path / "outside.txt"
    outside.write_text("keep me")
    out = tmp_path / "out"
    out.mkdir()
    (out / ".model.safetensors.part").symlink_to(outside)
    pull_model_with_key(store, cid, out, bytes(REQUESTER.key))
    assert outside.read_text() == "keep me"
    assert (out / "model.safetensors").read_bytes() == (
        model_dir / "model.safetensors"
    ).read_bytes()
