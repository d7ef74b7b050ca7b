"""Model provenance over the REST API: an outcome is the requester's to download before anyone
shares it, only its worker shares it (after acceptance), the declared environment must be the
one on the model's card, and a CID is listed once."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from backend.chain.errors import ContractError
from backend.services.chain import ChainService
from backend.store.bundle import add_bundle

from .conftest import ENV, Login, P, addr, register, task_body
from .test_models import card_of, weights_of

WORKERS = {"user3": {"cpu_cores": 16}, "user4": {"cpu_cores": 8}}


def test_outcome_download_and_sharing_follow_provenance(
    client: TestClient, login: Login, service: ChainService
) -> None:
    register(client, login, ["user1"], WORKERS)
    r = client.post(f"{P}/tasks", json=task_body(num_workers=2), headers=login("user1"))
    assert r.status_code == 201, r.text
    task_id, offered = r.json()["task_id"], r.json()["offered"]
    names = {addr(service, n): n for n in WORKERS}
    owner, other = offered[0], offered[1]
    store = client.app.state.store  # type: ignore[attr-defined]
    weights = weights_of("trained", 500)
    cid = add_bundle(store, {"model.safetensors": weights, "model.json": card_of(ENV, "o")})
    with service.lock:
        for w in offered:
            service.platform.tmc.transact("acceptOffer", task_id, sender=w)
        service.platform.tmc.transact("submitOutcome", task_id, cid, sender=owner)
    client.app.state.indexer.poll()  # type: ignore[attr-defined]

    # the requester (and the worker itself) download the outcome before it is shared
    url = f"{P}/models/outcomes/{task_id}/{owner}/download"
    r = client.get(url, headers=login("user1"))
    assert r.status_code == 200 and r.content == weights
    assert client.get(url, headers=login(names[owner])).content == weights
    r = client.get(url, headers=login(names[other]))
    assert r.status_code == 403 and r.json()["detail"]["rule"] == "not_task_requester"
    assert client.get(url).status_code == 401
    r = client.get(f"{P}/models/outcomes/{task_id}/{other}/download", headers=login("user1"))
    assert r.status_code == 404 and r.json()["detail"]["rule"] == "outcome_not_found"

    share = {"cid": cid, "env": ENV, "description": "outcome"}
    r = client.post(f"{P}/models", json=share, headers=login(names[other]))
    assert r.status_code == 403 and r.json()["detail"]["rule"] == "models_not_outcome_owner"
    r = client.post(f"{P}/models", json=share, headers=login(names[owner]))
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "models_outcome_not_accepted"

    r = client.post(
        f"{P}/tasks/{task_id}/reviews", json={"worker": owner, "review": 5}, headers=login("user1")
    )
    assert r.status_code == 200, r.text
    wrong = share | {"env": ENV | {"agents": 3}}
    r = client.post(f"{P}/models", json=wrong, headers=login(names[owner]))
    assert r.status_code == 422, r.text
    [issue] = r.json()["detail"]
    assert issue["loc"] == ["body", "env", "agents"] and issue["type"] == "env_mismatch_card"
    r = client.post(f"{P}/models", json=share, headers=login(names[owner]))
    assert r.status_code == 201, r.text
    assert r.json()["owner"] == owner and r.json()["cid"] == cid
    r = client.post(f"{P}/models", json=share, headers=login(names[owner]))
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "model_already_listed"
    assert client.get(f"{P}/models").json()["count"] == 1


def test_own_upload_needs_its_card(client: TestClient, login: Login) -> None:
    register(client, login, [], {"user3": {}})
    store = client.app.state.store  # type: ignore[attr-defined]
    cases = [
        (add_bundle(store, {"model.safetensors": b"w"}), "card_missing"),
        (add_bundle(store, {"model.json": b'{"format": "drlaas-model/1"}'}), "card_invalid"),
        (add_bundle(store, {"model.json": b"[1, 2"}), "card_invalid"),
        ("bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy", "bundle_not_found"),
    ]
    for cid, rule in cases:
        r = client.post(f"{P}/models", json={"cid": cid, "env": ENV}, headers=login("user3"))
        assert r.status_code == 422, r.text
        assert [(d["loc"], d["type"]) for d in r.json()["detail"]] == [(["body", "cid"], rule)]
    cid = add_bundle(
        store, {"model.safetensors": weights_of("w"), "model.json": card_of(ENV, "mine")}
    )
    r = client.post(f"{P}/models", json={"cid": cid, "env": ENV}, headers=login("user3"))
    assert r.status_code == 201, r.text


def test_a_listed_model_cannot_be_handed_in_as_an_outcome(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """Someone who hands another owner's listed model in as the outcome of its own task would
    pass that work off as its own and become the model's producer: the TMC refuses the CID
    (``setModels`` names the MMC at deployment), and the page names no producer."""
    register(client, login, ["user1"], {"user3": {}, "user4": {}})
    store = client.app.state.store  # type: ignore[attr-defined]
    cid = add_bundle(
        store, {"model.safetensors": weights_of("victim"), "model.json": card_of(ENV, "v")}
    )
    r = client.post(f"{P}/models", json={"cid": cid, "env": ENV}, headers=login("user3"))
    assert r.status_code == 201, r.text
    model_id = r.json()["id"]
    r = client.post(f"{P}/tasks", json=task_body(num_workers=2), headers=login("user1"))
    task_id, offered = r.json()["task_id"], r.json()["offered"]
    thief = next(w for w in offered if w == addr(service, "user4"))
    with service.lock:
        service.platform.tmc.transact("acceptOffer", task_id, sender=thief)
        with pytest.raises(ContractError) as refused:
            service.platform.tmc.transact("submitOutcome", task_id, cid, sender=thief)
    assert refused.value.name == "TasksOutcomeIsListedModel"
    assert refused.value.args_dict["modelId"] == model_id
    client.app.state.indexer.poll()  # type: ignore[attr-defined]
    page = client.get(f"{P}/models/{model_id}").json()
    assert page["produced_by"] is None and page["owner"] == addr(service, "user3")
