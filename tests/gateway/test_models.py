"""Models: share via the API, search by domain/agents/walls/reputation/text, allocation and
reviews moving Eq. 11 reputation, verified download bounded by the manifest."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient
from safetensors.numpy import save as save_safetensors

from backend.services.chain import ChainService
from backend.services.specs import validate_env
from backend.store.bundle import add_bundle, bundle_entry, canonical_json

from .conftest import Login, P, addr, register

ENV3 = {"rows": 10, "cols": 10, "agents": 3, "walls": [0, 2]}
ENV2 = {"rows": 10, "cols": 10, "agents": 2, "walls": [3, 3]}


def card_of(env: dict, text: str) -> bytes:
    """A model card as workers/mdrl/modelio.py writes it (the fields the gateway reads)."""
    card = {
        "format": "drlaas-model/1",
        "env": validate_env(env).to_dict(),
        "observation": {"kind": "odmtl", "window": 3},  # what an expert is sized by
        "metrics": {"success": 0.9},
        "name": text,
    }
    return canonical_json(card)


def weights_of(text: str, n: int = 1) -> bytes:
    """``model.safetensors`` bytes (the gateway lists and accepts safetensors weights only)."""
    return save_safetensors({"w": np.ones(n, np.float32)}, metadata={"name": text})


def _share(client: TestClient, login: Login, name: str, env: dict, domain: int, text: str) -> dict:
    store = client.app.state.store  # type: ignore[attr-defined]
    weights = weights_of(text, 1000)
    card = card_of(env, text)
    cid = add_bundle(store, {"model.safetensors": weights, "model.json": card})
    r = client.post(
        f"{P}/models",
        json={"cid": cid, "description": text, "domain": domain, "env": env},
        headers=login(name),
    )
    assert r.status_code == 201, r.text
    return r.json() | {"_weights": weights}


def test_search_allocate_review_download(
    client: TestClient, login: Login, service: ChainService
) -> None:
    register(
        client,
        login,
        ["user1"],
        {"user3": {"domains": [0, 1]}, "user4": {"domains": [0]}},
    )
    a = _share(client, login, "user3", ENV3, 0, "three agents open field")
    b = _share(client, login, "user4", ENV2, 0, "two agents walled")
    c = _share(client, login, "user3", ENV3, 1, "other domain")
    assert a["env"] == [10, 10, 3, 4, 0, 2] and a["owner"] == addr(service, "user3")

    def ids(**params: object) -> list[int]:
        r = client.get(f"{P}/models", params=params | {"sort": "newest"})
        assert r.status_code == 200, r.text
        assert r.json()["count"] == len(r.json()["data"])
        return sorted(m["id"] for m in r.json()["data"])

    assert ids() == sorted([a["id"], b["id"], c["id"]])
    assert ids(domain=0) == sorted([a["id"], b["id"]])
    assert ids(agents=3) == sorted([a["id"], c["id"]])
    assert ids(walls=3) == [b["id"]]
    assert ids(walls=1, domain=0) == [a["id"]]
    assert ids(q="walled") == [b["id"]]
    assert ids(q="AGENTS Two") == [b["id"]]  # every word, in any order and case
    assert ids(q="agents field") == [a["id"]]
    assert ids(q="agents other") == []
    assert ids(q=f"#{c['id']}") == [c["id"]]  # a model id
    assert ids(q=addr(service, "user4")[2:12].lower()) == [b["id"]]  # part of the owner
    assert ids(q=b["cid"][-12:]) == [b["id"]]
    assert ids(q="walled ³") == []  # not a number: only text
    assert ids(q="%") == []  # LIKE wildcards are literal
    r = client.get(f"{P}/models", params={"q": "\x00"})  # SQLite's LIKE stops at a NUL
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["query", "q"]
    assert ids(owner=addr(service, "user4").lower()) == [b["id"]]

    # allocation: the requester asks for one model like ENV2 in domain 0, then reviews it 5/5
    r = client.post(
        f"{P}/models/requests",
        json={"domain": 0, "env": ENV2, "num_models": 1},  # price: the minimum
        headers=login("user1"),
    )
    assert r.status_code == 201, r.text
    alloc = r.json()
    assert [m["id"] for m in alloc["models"]] == [b["id"]]  # closest environment wins (Eq. 22)
    assert alloc["models"][0]["cid"] == b["cid"]
    r = client.post(
        f"{P}/models/requests/{alloc['alloc_id']}/reviews",
        json={"model_id": b["id"], "review": 5},
        headers=login("user4"),  # not the requester
    )
    assert r.status_code == 403
    r = client.post(
        f"{P}/models/requests/{alloc['alloc_id']}/reviews",
        json={"model_id": b["id"], "review": 5},
        headers=login("user1"),
    )
    assert r.status_code == 200, r.text
    detail = client.get(f"{P}/models/{b['id']}").json()
    assert detail["reputation"] == 1.0 and detail["allocations"] == 1  # Eq. 11: 5 / (1 * 5)
    again = client.post(
        f"{P}/models/requests/{alloc['alloc_id']}/reviews",
        json={"model_id": b["id"], "review": 1},
        headers=login("user1"),
    )
    assert again.status_code == 409 and again.json()["detail"]["rule"] == "model_already_reviewed"
    assert detail["card"]["name"] == "two agents walled" and detail["metrics"] == {"success": 0.9}
    assert ids(min_reputation=0.6) == [b["id"]]
    top = client.get(f"{P}/models", params={"sort": "reputation"}).json()["data"]
    assert top[0]["id"] == b["id"]

    # download: exact bytes, with the file's CID, and a corrupted block is never served
    r = client.get(f"{P}/models/{b['id']}/download")
    assert r.status_code == 200 and r.content == b["_weights"]
    store = client.app.state.store  # type: ignore[attr-defined]
    file_cid, size = bundle_entry(store, b["cid"], "model.safetensors")
    assert r.headers["x-content-cid"] == file_cid and int(r.headers["content-length"]) == size
    assert (
        client.get(f"{P}/models/{b['id']}/download", params={"file": "model.json"}).json()["name"]
        == "two agents walled"
    )
    assert client.get(f"{P}/models/{b['id']}/download", params={"file": "x.bin"}).status_code == 422
    block = Path(store.block_path(file_cid))
    block.write_bytes(b"tampered" + block.read_bytes()[8:])
    r = client.get(f"{P}/models/{b['id']}/download")
    assert r.status_code == 502 and r.json()["detail"]["rule"] == "content_corrupt"
    assert client.get(f"{P}/models/999/download").status_code == 404


def test_share_validation_and_roles(client: TestClient, login: Login) -> None:
    register(client, login, ["user1"], {"user3": {}})
    cid = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
    bad = [
        ({"cid": "not-a-cid", "env": ENV3}, ["body", "cid"]),
        ({"cid": cid, "env": ENV3 | {"agents": 0}}, ["body", "env", "agents"]),
        ({"cid": cid, "env": ENV3, "domain": -1}, ["body", "domain"]),
    ]
    for body, loc in bad:
        r = client.post(f"{P}/models", json=body, headers=login("user3"))
        assert r.status_code == 422, r.text
        assert loc in [d["loc"][: len(loc)] for d in r.json()["detail"]]
    store = client.app.state.store  # type: ignore[attr-defined]
    cid = add_bundle(
        store, {"model.safetensors": weights_of("x"), "model.json": card_of(ENV3, "x")}
    )
    r = client.post(f"{P}/models", json={"cid": cid, "env": ENV3}, headers=login("user1"))
    assert r.status_code == 403 and r.json()["detail"]["rule"] == "models_not_worker"
    r = client.post(
        f"{P}/models/requests",
        json={"env": ENV3, "weights": [1, 2]},
        headers=login("user1"),
    )
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "weights"]
    r = client.post(f"{P}/models/requests", json={"env": ENV3}, headers=login("user1"))
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "models_no_eligible_model"
