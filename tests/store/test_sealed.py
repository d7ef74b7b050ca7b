"""Sealed outcomes (backend/store/sealed.py): only the recipient reads the weights, the chain's
CID stays the plaintext bundle's, and nothing tampered or misaddressed opens."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from eth_account import Account

from backend.store import EmbeddedStore, InvalidContent, NotFound
from backend.store.bundle import canonical_json, pull_model, read_bundle, upload_model
from backend.store.sealed import (
    SealedContent,
    address_of,
    open_sealed,
    parse_public_key,
    public_key_hex,
    publish_model,
    pull_model_with_key,
    read_envelope,
    seal_model,
    sealed_envelopes,
)

REQUESTER = Account.from_key("0x" + "11" * 32)
OTHER = Account.from_key("0x" + "22" * 32)


def _pub(account) -> bytes:  # noqa: ANN001
    return parse_public_key(public_key_hex(bytes(account.key)))


def test_public_key_is_the_accounts(store: EmbeddedStore) -> None:
    assert address_of(_pub(REQUESTER)) == REQUESTER.address
    with pytest.raises(ValueError, match="64-byte"):
        parse_public_key("0x1234")
    with pytest.raises(ValueError, match="not a point"):
        parse_public_key("0x" + "01" * 64)
    with pytest.raises(ValueError, match="hex"):
        parse_public_key("0x" + "zz" * 64)


def test_sealed_bundle_has_the_plaintext_cid_but_not_the_weights(
    store: EmbeddedStore, model_dir: Path, tmp_path: Path
) -> None:
    cid = seal_model(store, model_dir, _pub(REQUESTER))
    plain_store = EmbeddedStore(tmp_path / "plain")
    files = read_bundle(store, cid)
    # the same files uploaded in clear give the same file CIDs: provenance is unchanged
    assert files == read_bundle(plain_store, upload_model(plain_store, model_dir))
    weights_cid, _ = files["model.safetensors"]
    assert not store.has(weights_cid)  # a third party with the chain's CID gets no weights
    assert store.get(files["model.json"][0]) == (model_dir / "model.json").read_bytes()
    with pytest.raises(NotFound):
        pull_model(store, cid, tmp_path / "anyone")
    with pytest.raises(SealedContent, match="sealed to the task's requester"):
        pull_model_with_key(store, cid, tmp_path / "anyone", None)
    out = pull_model_with_key(store, cid, tmp_path / "requester", bytes(REQUESTER.key))
    for name in ("model.safetensors", "model.json"):
        assert (out / name).read_bytes() == (model_dir / name).read_bytes()


def test_wrong_key_is_refused(store: EmbeddedStore, model_dir: Path) -> None:
    cid = seal_model(store, model_dir, _pub(REQUESTER))
    with pytest.raises(SealedContent, match=REQUESTER.address):
        open_sealed(store, cid, "model.safetensors", bytes(OTHER.key))


def test_tampered_ciphertext_or_envelope_fails(store: EmbeddedStore, model_dir: Path) -> None:
    cid = seal_model(store, model_dir, _pub(REQUESTER))
    manifest = json.loads(store.get(cid))
    env_cid = sealed_envelopes(store, cid)["model.safetensors"]
    env = read_envelope(store, env_cid)
    cipher = bytearray(store.get(env["cipher"]))
    cipher[40] ^= 1
    forged_env = dict(env, cipher=store.add(bytes(cipher)))
    forged = dict(manifest, sealed={"model.safetensors": store.add(canonical_json(forged_env))})
    with pytest.raises(InvalidContent, match="fails authentication"):
        open_sealed(
            store, store.add(canonical_json(forged)), "model.safetensors", bytes(REQUESTER.key)
        )
    # an envelope of another model cannot stand in for this one
    other = model_dir.parent / "other"
    other.mkdir()
    (other / "model.safetensors").write_bytes(os.urandom(3000))
    (other / "model.json").write_bytes((model_dir / "model.json").read_bytes())
    other_env = sealed_envelopes(store, seal_model(store, other, _pub(REQUESTER)))
    swapped = dict(manifest, sealed=other_env)
    with pytest.raises(InvalidContent, match="another file"):
        open_sealed(
            store, store.add(canonical_json(swapped)), "model.safetensors", bytes(REQUESTER.key)
        )


def test_publishing_makes_the_weights_public(
    store: EmbeddedStore, model_dir: Path, tmp_path: Path
) -> None:
    cid = seal_model(store, model_dir, _pub(REQUESTER))
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "model.safetensors").write_bytes(b"not the weights")
    (bad / "model.json").write_bytes((model_dir / "model.json").read_bytes())
    with pytest.raises(ValueError, match="is not the model.safetensors"):
        publish_model(store, cid, bad)
    publish_model(store, cid, model_dir)
    out = pull_model(store, cid, tmp_path / "anyone")
    assert (out / "model.safetensors").read_bytes() == (
        model_dir / "model.safetensors"
    ).read_bytes()


def test_pulling_a_model_refuses_files_beyond_a_models_bounds(
    store: EmbeddedStore, model_dir: Path, tmp_path: Path
) -> None:
    """A manifest may declare any size, and a store that keeps identical blocks once holds
    256 MiB of zeros in a few hundred kB: `drlaas model pull` and `task pull` (plain or sealed)
    write no model file beyond the worker's bounds on an expert, and nothing at all then."""
    from backend.store.bundle import MAX_MODEL_FILE_BYTES, MODEL_FILES

    good = read_bundle(store, upload_model(store, model_dir))
    for name in MODEL_FILES:
        entries = {n: {"cid": c, "size": size} for n, (c, size) in good.items()}
        entries[name]["size"] = MAX_MODEL_FILE_BYTES[name] + 1
        cid = store.add(canonical_json({"format": "drlaas-bundle/1", "files": entries}))
        for pull in (pull_model, lambda s, c, d: pull_model_with_key(s, c, d, None)):
            with pytest.raises(InvalidContent, match=f"{name} of bundle {cid} declares"):
                pull(store, cid, tmp_path / "out")
            assert not list((tmp_path / "out").glob("*"))
