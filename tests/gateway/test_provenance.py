"""Model provenance over the REST API: an outcome is the requester's to download before anyone
shares it, only its worker shares it (after acceptance), the declared environment must be the
one on the model's card, and a CID is listed once."""

from __future__ import annotations

from typing import Any

import pytest
from eth_account import Account
from fastapi.testclient import TestClient

from backend.chain.errors import ContractError
from backend.chain.platform import cid_commitment
from backend.services.chain import ChainService
from backend.store.bundle import add_bundle
from backend.store.staged import StagedUpload

from .conftest import ENV, Login, P, addr, fund, register, task_body
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
        service.platform.tmc.submit_outcome(owner, task_id, cid)
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
    [unshared] = client.get(f"{P}/tasks/{task_id}").json()["outcomes"]
    assert unshared["cid"] == cid and unshared["model_id"] is None

    r = client.post(
        f"{P}/tasks/{task_id}/reviews", json={"worker": owner, "review": 5}, headers=login("user1")
    )
    assert r.status_code == 200, r.text
    wrong = share | {"env": ENV | {"agents": 3}}
    r = client.post(f"{P}/models", json=wrong, headers=login(names[owner]))
    assert r.status_code == 422, r.text
    [issue] = r.json()["detail"]
    assert issue["loc"] == ["body", "env", "agents"] and issue["type"] == "env_mismatch_card"
    # its requester's acceptance vouches for the task's domain (0), not another one
    r = client.post(f"{P}/models", json=share | {"domain": 1}, headers=login(names[owner]))
    assert r.status_code == 409, r.text
    assert r.json()["detail"]["rule"] == "models_outcome_domain_mismatch"
    assert "domain 0" in r.json()["detail"]["msg"]
    r = client.post(f"{P}/models", json=share, headers=login(names[owner]))
    assert r.status_code == 201, r.text
    assert r.json()["owner"] == owner and r.json()["cid"] == cid
    [listed] = client.get(f"{P}/tasks/{task_id}").json()["outcomes"]
    assert listed["model_id"] == r.json()["id"]  # the task page links the outcome to its model
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
            service.platform.tmc.submit_outcome(thief, task_id, cid)
    assert refused.value.name == "TasksOutcomeIsListedModel"
    assert refused.value.args_dict["modelId"] == model_id
    client.app.state.indexer.poll()  # type: ignore[attr-defined]
    page = client.get(f"{P}/models/{model_id}").json()
    assert page["produced_by"] is None and page["owner"] == addr(service, "user3")


def test_sharing_an_own_upload_commits_its_cid_first(
    client: TestClient, service: ChainService, settings: Any
) -> None:
    """Commit-reveal over REST for a key the gateway does not hold: ``POST /models`` first
    answers the commitment to sign (``then: repeat``); relayed, the same request answers the
    listing itself, mined a block after the commitment; the model is the caller's."""
    from backend.auth import DemoKeys, bearer_headers

    me = Account.create()
    fund(service, me.address)  # gas for the new account
    own = DemoKeys(settings)  # the client's keys, not the gateway's
    own.add("me", me)
    headers = dict(bearer_headers(own.sign_in(client, "me")))

    def relayed(r: Any) -> dict[str, Any]:
        assert r.status_code == 409 and r.json()["detail"]["rule"] == "sign_locally", r.text
        tx = dict(r.json()["detail"]["tx"])
        tx.pop("from")
        raw = "0x" + bytes(me.sign_transaction(tx).raw_transaction).hex()
        out = client.post(f"{P}/tx", json={"raw": raw}, headers=headers)
        assert out.status_code == 200, out.text
        return out.json()

    body = {"domains": [0], "cpu_cores": 4, "ram_gb": 8, "gpu_series": 0}
    relayed(client.post(f"{P}/users/workers", json=body, headers=headers))
    store = client.app.state.store  # type: ignore[attr-defined]
    files = {"model.safetensors": weights_of("mine"), "model.json": card_of(ENV, "m")}
    cid = add_bundle(store, files)
    first = client.post(f"{P}/models", json={"cid": cid, "env": ENV}, headers=headers)
    detail = first.json()["detail"]
    assert detail.get("then") == "repeat" and "send this request again" in detail["msg"]
    assert detail["tx"]["to"] == service.platform.tmc.address
    commit = relayed(first)
    commitment = cid_commitment(cid, me.address)
    assert service.platform.tmc.call("cidCommits", commitment) == commit["block_number"]
    second = client.post(f"{P}/models", json={"cid": cid, "env": ENV}, headers=headers)
    assert "then" not in second.json()["detail"]  # the listing itself
    assert second.json()["detail"]["tx"]["to"] == service.platform.mmc.address
    listing = relayed(second)
    assert listing["block_number"] > commit["block_number"]
    model_id = service.platform.mmc.model_of_cid(cid)
    assert service.platform.mmc.call("getModel", model_id)[0][0] == me.address


def test_a_commitment_made_before_the_upload_is_what_listing_reveals(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """``POST /models/commitments`` (what ``drlaas model push --key`` sends before it uploads):
    workers only; a repeat keeps the first block; the listing then sends no new commitment."""
    register(client, login, ["user1"], {"user3": {}})
    files = {"model.safetensors": weights_of("early"), "model.json": card_of(ENV, "e")}
    cid = StagedUpload()
    manifest = add_bundle(cid, files)  # the CID, computed without storing anything
    commitment = "0x" + cid_commitment(manifest, addr(service, "user3")).hex()
    body = {"commitment": commitment}
    r = client.post(f"{P}/models/commitments", json=body, headers=login("user1"))
    assert r.status_code == 403 and r.json()["detail"]["rule"] == "tasks_not_worker", r.text
    bad = client.post(
        f"{P}/models/commitments", json={"commitment": "0x12"}, headers=login("user3")
    )
    assert bad.status_code == 422
    r = client.post(f"{P}/models/commitments", json=body, headers=login("user3"))
    assert r.status_code == 201, r.text
    block = r.json()["block"]
    again = client.post(f"{P}/models/commitments", json=body, headers=login("user3"))
    assert again.json()["block"] == block
    cid.publish(client.app.state.store)  # type: ignore[attr-defined]
    r = client.post(f"{P}/models", json={"cid": manifest, "env": ENV}, headers=login("user3"))
    assert r.status_code == 201, r.text
    commits = service.platform.tmc.contract.events.CidCommitted().get_logs(from_block=block)
    assert [e["args"]["commitment"].hex() for e in commits] == [commitment[2:]]
