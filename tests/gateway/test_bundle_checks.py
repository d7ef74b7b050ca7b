"""The gateway's check of a model bundle (backend/api/bundles.py), run on the bundle its content
store holds before it lists it on the MMC (POST /models) or accepts it as a task's expert
(POST /tasks ``experts``): bundles the workers refuse (pickle, torch.save or empty weights, a
safetensors header length of 10^18, a path in the manifest, a card of another format, ...) are
422 naming the rule and the problem, and nothing reaches the chain; valid bundles still pass."""

from __future__ import annotations

import io
import json
import os
import pickle
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from fastapi.testclient import TestClient
from safetensors.numpy import save as save_safetensors

from backend.chain.platform import cid_hash
from backend.services.chain import ChainService
from backend.services.specs import validate_env
from backend.store.bundle import BUNDLE_FORMAT, add_bundle, canonical_json

from .conftest import Login, P, register, task_body

ENV = {"rows": 10, "cols": 10, "agents": 2, "walls": [0, 2]}
ZOO = Path(__file__).resolve().parents[2] / "models"
ZOO_MODEL = ZOO / "odmtl-2a"
ZOO_CAE = ZOO / "cae-10x10"  # grid 10 x 10, d = 32
TENSORS = {"actor.w": np.ones((4, 3), np.float32), "critic.b": np.zeros(2, np.float32)}
GOOD_WEIGHTS = save_safetensors(TENSORS)
# its header is 128 bytes: the file starts with 0x80 as a pickle does, and is no pickle
assert GOOD_WEIGHTS[:8] == struct.pack("<Q", 128)


def card(**over: Any) -> bytes:
    doc = {"format": "drlaas-model/1", "env": validate_env(ENV).to_dict(), "name": "m",
           "observation": {"kind": "odmtl", "window": 3}}
    return canonical_json(doc | over)


def header_only(header: dict[str, Any], data: bytes = b"") -> bytes:
    raw = json.dumps(header).encode()
    return struct.pack("<Q", len(raw)) + raw + data


def torch_save() -> bytes:
    buf = io.BytesIO()
    torch.save({"w": torch.zeros(3)}, buf)
    return buf.getvalue()


ABSENT = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
"""A CID the store does not hold."""


def manifest(
    store: Any,
    files: dict[str, tuple[bytes, int | None]],
    absent: dict[str, tuple[str, int]] | None = None,
) -> str:
    """A bundle whose manifest declares the given sizes (None: the true one), and names
    ``absent`` files by CIDs the store does not hold."""
    entries = {
        name: {"cid": store.add(data), "size": len(data) if size is None else size}
        for name, (data, size) in files.items()
    }
    entries |= {name: {"cid": cid, "size": size} for name, (cid, size) in (absent or {}).items()}
    return str(store.add(canonical_json({"format": BUNDLE_FORMAT, "files": entries})))


Bundle = Callable[[Any], str]


def weights(data: bytes) -> Bundle:
    return lambda store: add_bundle(store, {"model.safetensors": data, "model.json": card()})


# name: (bundle in the store, rule of POST /models, what the message must name)
BAD: dict[str, tuple[Bundle, str, str]] = {
    "pickle": (
        weights(pickle.dumps({"evil": os.system})),
        "weights_not_safetensors",
        "model.safetensors is a pickle",
    ),
    "path in manifest": (
        lambda s: add_bundle(
            s,
            {"model.safetensors": GOOD_WEIGHTS, "model.json": card(), "../../../tmp/x": b"x"},
        ),
        "bundle_file_name_invalid",
        "'../../../tmp/x'",
    ),
    "extra plain file": (
        lambda s: add_bundle(
            s, {"model.safetensors": GOOD_WEIGHTS, "model.json": card(), "notes.txt": b"x"}
        ),
        "bundle_files_invalid",
        "unexpected ['notes.txt']",
    ),
    "card format": (
        lambda s: add_bundle(
            s, {"model.safetensors": GOOD_WEIGHTS, "model.json": card(format="other/1")}
        ),
        "card_format_invalid",
        "format 'other/1'",
    ),
    "empty weights": (weights(b""), "weights_empty", "model.safetensors is empty"),
    "torch.save weights": (
        weights(torch_save()),
        "weights_not_safetensors",
        "a zip archive (torch.save)",
    ),
    "header length 10^18": (
        weights(struct.pack("<Q", 10**18) + b"{}"),
        "weights_not_safetensors",
        "header length 1000000000000000000",
    ),
    "short weights": (weights(b"w"), "weights_not_safetensors", "too short"),
    "no tensor": (weights(header_only({})), "weights_empty", "holds no tensor"),
    "empty tensor": (
        weights(header_only({"t": {"dtype": "F32", "shape": [0], "data_offsets": [0, 0]}})),
        "weights_empty",
        "tensor 't' is empty",
    ),
    "tensor past the data": (
        weights(header_only({"t": {"dtype": "F32", "shape": [4], "data_offsets": [0, 16]}}, b"x")),
        "weights_not_safetensors",
        "not a valid safetensors file",
    ),
    "unsupported dtype": (
        weights(
            header_only({"t": {"dtype": "F8_E4M3", "shape": [1], "data_offsets": [0, 1]}}, b"\0")
        ),
        "weights_dtype_unsupported",
        "F8_E4M3",
    ),
    "weights unlike the card": (
        lambda s: add_bundle(
            s,
            {
                "model.safetensors": GOOD_WEIGHTS,
                "model.json": card(architecture={"tensors": {"actor.w": [4, 4], "critic.b": [2]}}),
            },
        ),
        "weights_mismatch_card",
        "tensor 'actor.w' has shape [4, 3]",
    ),
    "declared over the bound": (
        lambda s: manifest(
            s, {"model.safetensors": (GOOD_WEIGHTS, 2**40), "model.json": (card(), None)}
        ),
        "weights_too_large",
        "1099511627776 bytes",
    ),
    "larger than declared": (
        lambda s: manifest(
            s,
            {
                "model.safetensors": (GOOD_WEIGHTS, len(GOOD_WEIGHTS) - 8),
                "model.json": (card(), None),
            },
        ),
        "bundle_size_mismatch",
        "larger than its manifest says",
    ),
    "weights not in the store": (
        lambda s: manifest(s, {"model.json": (card(), None)}, {"model.safetensors": (ABSENT, 100)}),
        "bundle_file_not_found",
        "does not hold its model.safetensors",
    ),
}


def _listed(service: ChainService, cid: str) -> int:
    return int(service.call(service.platform.mmc, "modelOfCid", cid_hash(cid)))


def test_share_refuses_bundles_the_workers_refuse(
    client: TestClient, login: Login, service: ChainService
) -> None:
    register(client, login, [], {"user3": {}})
    store = client.app.state.store  # type: ignore[attr-defined]
    for name, (make, rule, fragment) in BAD.items():
        cid = make(store)
        r = client.post(
            f"{P}/models",
            json={"cid": cid, "env": ENV, "description": name},
            headers=login("user3"),
        )
        assert r.status_code == 422, (name, r.text)
        [issue] = r.json()["detail"]
        assert (issue["type"], issue["loc"]) == (rule, ["body", "cid"]), (name, issue)
        assert fragment in issue["msg"], (name, issue["msg"])
        assert _listed(service, cid) == 0, name  # nothing was sent to the MMC
    assert client.get(f"{P}/models").json()["count"] == 0

    # a valid bundle is still listed: a minimal one, and a zoo model as save_model wrote it
    good = add_bundle(store, {"model.safetensors": GOOD_WEIGHTS, "model.json": card()})
    r = client.post(f"{P}/models", json={"cid": good, "env": ENV}, headers=login("user3"))
    assert r.status_code == 201, r.text
    assert _listed(service, good) == r.json()["id"]
    zoo = {n: (ZOO_MODEL / n).read_bytes() for n in ("model.safetensors", "model.json")}
    zoo_cid = add_bundle(store, zoo)
    body = {"cid": zoo_cid, "env": json.loads(zoo["model.json"])["env"]}
    r = client.post(f"{P}/models", json=body, headers=login("user3"))
    assert r.status_code == 201, r.text


def test_a_task_naming_such_a_bundle_as_expert_is_refused(client: TestClient, login: Login) -> None:
    register(client, login, ["user1"], {"user3": {}})
    store = client.app.state.store  # type: ignore[attr-defined]
    good = add_bundle(store, {"model.safetensors": GOOD_WEIGHTS, "model.json": card()})
    for name, (make, rule, fragment) in BAD.items():
        cid = make(store)
        r = client.post(f"{P}/tasks", json=task_body(experts=[good, cid]), headers=login("user1"))
        assert r.status_code == 422, (name, r.text)
        issue = r.json()["detail"][0]
        want = "expert_not_found" if rule == "bundle_file_not_found" else "expert_invalid"
        assert (issue["type"], issue["loc"]) == (want, ["body", "experts", 1]), (name, issue)
        assert fragment in issue["msg"] and f"({rule})" in issue["msg"], (name, issue["msg"])
    assert client.get(f"{P}/tasks").json()["count"] == 0
    r = client.post(f"{P}/tasks", json=task_body(experts=[good]), headers=login("user1"))
    assert r.status_code == 201, r.text

    # the zoo's bundles as save_model / save_cae wrote them: an expert, and a walls CAE
    def zoo(path: Path) -> str:
        return add_bundle(
            store, {n: (path / n).read_bytes() for n in ("model.safetensors", "model.json")}
        )

    env = {"rows": 10, "cols": 10, "agents": 2, "max_steps": 50}
    obs = {
        "kind": "odmtl",
        "window": 3,
        "walls_embedding": zoo(ZOO_CAE),
        "walls_embedding_size": 32,
    }
    body = task_body(env=env, observation=obs, experts=[zoo(ZOO_MODEL)])
    r = client.post(f"{P}/tasks", json=body, headers=login("user1"))
    assert r.status_code == 201, r.text
    # a pickle as the walls CAE's weights is refused as for an expert
    cae_card = (ZOO_CAE / "model.json").read_bytes()
    bad_cae = add_bundle(store, {"model.safetensors": pickle.dumps(1), "model.json": cae_card})
    r = client.post(
        f"{P}/tasks",
        json=task_body(env=env, observation=obs | {"walls_embedding": bad_cae}),
        headers=login("user1"),
    )
    assert r.status_code == 422, r.text
    issue = r.json()["detail"][0]
    assert (issue["type"], issue["loc"]) == (
        "walls_cae_invalid",
        ["body", "observation", "walls_embedding"],
    )
    assert "model.safetensors is a pickle" in issue["msg"]
