"""Experts of a training task through the gateway (backend/api/experts.py): an MMC allocation
read back, its models and QoS written into the task spec, the caller's ownership of the
allocation, expert CIDs checked, the task page listing its experts with their review."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient

from backend.services.chain import ChainService
from backend.store.bundle import add_bundle, canonical_json

from .conftest import ENV, Login, P, addr, register, task_body
from .test_models import ENV2, ENV3, _share, card_of, weights_of


def test_experts_from_an_allocation_named_checked_and_reviewed(
    client: TestClient, login: Login, service: ChainService
) -> None:
    register(client, login, ["user1", "user2"], {"user3": {}, "user4": {}})
    a = _share(client, login, "user3", ENV2, 0, "two agents walled")
    b = _share(client, login, "user4", ENV3, 0, "three agents")
    r = client.post(
        f"{P}/models/requests",
        json={"domain": 0, "env": ENV2, "num_models": 2},
        headers=login("user1"),
    )
    assert r.status_code == 201, r.text
    alloc = r.json()
    got = client.get(f"{P}/models/requests/{alloc['alloc_id']}")
    assert got.status_code == 200, got.text
    detail = got.json()
    assert detail["requester"] == addr(service, "user1") and detail["num_models"] == 2
    assert [(x["id"], x["cid"], x["qos"]) for x in detail["models"]] == [
        (x["id"], x["cid"], x["qos"]) for x in alloc["models"]
    ]
    owners = {x["owner"] for x in detail["models"]}
    assert owners == {addr(service, "user3"), addr(service, "user4")}
    assert [x["review"] for x in detail["models"]] == [None, None]
    mine = client.get(f"{P}/models/requests", params={"requester": addr(service, "user1")})
    assert [x["alloc_id"] for x in mine.json()["data"]] == [alloc["alloc_id"]]
    assert (
        client.get(f"{P}/models/requests", params={"requester": addr(service, "user2")}).json()[
            "data"
        ]
        == []
    )
    assert client.get(f"{P}/models/requests/99").json()["detail"]["rule"] == "allocation_not_found"

    # another requester cannot use (nor see in its spec) user1's paid allocation
    body = task_body(expert_allocation=alloc["alloc_id"])
    r = client.post(f"{P}/tasks", json=body, headers=login("user2"))
    assert r.status_code == 403 and r.json()["detail"]["rule"] == "not_allocation_requester"
    r = client.post(f"{P}/tasks", json=task_body(expert_allocation=77), headers=login("user1"))
    assert r.status_code == 422 and r.json()["detail"][0]["type"] == "allocation_not_found"
    both = task_body(expert_allocation=alloc["alloc_id"], experts=[a["cid"]])
    r = client.post(f"{P}/tasks", json=both, headers=login("user1"))
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "expert_allocation"]

    r = client.post(f"{P}/tasks", json=body, headers=login("user1"))
    assert r.status_code == 201, r.text
    task = client.get(f"{P}/tasks/{r.json()['task_id']}").json()
    by_cid = {x["model"]: x["qos"] for x in task["spec"]["experts"]}
    assert by_cid == {x["cid"]: x["qos"] for x in alloc["models"]}  # the QoS the MMC emitted
    shown = {x["cid"]: x for x in task["experts"]}
    assert set(shown) == {a["cid"], b["cid"]}
    assert (
        shown[a["cid"]]["model_id"] == a["id"] and shown[a["cid"]]["alloc_id"] == alloc["alloc_id"]
    )
    # Eq. 11: allocated once, not reviewed yet
    assert shown[a["cid"]]["review"] is None and shown[a["cid"]]["reputation"] == 0.0

    # the requester reviews an expert it used: the task page and the listing show it
    r = client.post(
        f"{P}/models/requests/{alloc['alloc_id']}/reviews",
        json={"model_id": a["id"], "review": 5},
        headers=login("user1"),
    )
    assert r.status_code == 200, r.text
    task = client.get(f"{P}/tasks/{task['id']}").json()
    shown = {x["cid"]: x for x in task["experts"]}
    assert shown[a["cid"]]["review"] == 5 and shown[a["cid"]]["reputation"] == 1.0
    assert shown[b["cid"]]["review"] is None
    listed = {x["id"]: x for x in client.get(f"{P}/models").json()["data"]}
    assert listed[a["id"]]["reputation"] == 1.0 and listed[b["id"]]["reputation"] < 1.0
    # the owners' Eq. 10 reputations, as the MMC's OwnerRecords hold them: a page shows the
    # reputation Model-metric requests filter on, next to the sharing one (Eq. 19)
    for model, owner, rep in ((a, "user3", 1.0), (b, "user4", 0.0)):
        page = client.get(f"{P}/models/{model['id']}").json()
        allocs, reviews = service.platform.mmc.call("ownerRep", addr(service, owner))[:2]
        assert (allocs, reviews) == (1, 5 if rep else 0)
        assert page["owner_model_reputation"] == rep


def test_named_experts_must_be_model_cids_in_the_store(client: TestClient, login: Login) -> None:
    register(client, login, ["user1"], {"user3": {}})
    store = client.app.state.store  # type: ignore[attr-defined]
    model = add_bundle(
        store, {"model.safetensors": weights_of("m"), "model.json": card_of(ENV2, "m")}
    )
    loose = store.add(b"just some bytes")
    not_card = add_bundle(
        store, {"model.safetensors": weights_of("n"), "model.json": b'{"format": "x"}'}
    )
    absent = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
    cases = {
        "oracle": "expert_not_cid",
        "runs/m": "expert_not_cid",
        absent: "expert_not_found",
        loose: "expert_invalid",
        not_card: "expert_invalid",
    }
    for ref, rule in cases.items():
        r = client.post(f"{P}/tasks", json=task_body(experts=[model, ref]), headers=login("user1"))
        assert r.status_code == 422, (ref, r.text)
        err = r.json()["detail"][0]
        assert (err["type"], err["loc"]) == (rule, ["body", "experts", 1]), (ref, err)
    r = client.post(
        f"{P}/tasks",
        json=task_body(experts=[{"model": model, "qos": 0.3}]),
        headers=login("user1"),
    )
    assert r.status_code == 201, r.text
    # the OpenAPI document states the rule: every model reference of a task is a CID
    body = client.get(f"{P}/openapi.json").json()["components"]["schemas"]["TaskCreate"]
    item = body["properties"]["experts"]["items"]["anyOf"]
    cae = body["properties"]["observation"]["properties"]["walls_embedding"]["anyOf"][0]
    for ref_schema in (item[0], item[1]["properties"]["model"], cae):
        pattern = re.compile(ref_schema["pattern"])
        assert pattern.search(model) and not pattern.search("runs/m")
        assert not pattern.search("oracle")


def test_a_named_walls_cae_must_be_a_cae_bundle_in_the_store(
    client: TestClient, login: Login
) -> None:
    """observation.walls_embedding (Ch. 4): a canonical CID of a bundle whose card is a walls
    CAE's; a policy's bundle, bytes or an absent CID are 422 naming the field."""
    register(client, login, ["user1"], {"user3": {}})
    store = client.app.state.store  # type: ignore[attr-defined]

    def cae_bundle(grid: list[int], channels: Any = (4, 8)) -> str:
        card = {"format": "drlaas-model/1", "kind": "cae", "grid": grid, "embedding": 8}
        if channels is not None:
            card["architecture"] = {"channels": list(channels)}
        return add_bundle(
            store, {"model.safetensors": weights_of("c"), "model.json": json.dumps(card).encode()}
        )

    cae = cae_bundle([ENV["rows"], ENV["cols"]])
    other_grid = cae_bundle([6, 6])
    policy = add_bundle(
        store, {"model.safetensors": weights_of("p"), "model.json": card_of(ENV2, "m")}
    )
    absent = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"

    def post(ref: str, size: int = 8) -> Any:
        obs = {"kind": "odmtl", "window": 3, "walls_embedding": ref, "walls_embedding_size": size}
        return client.post(f"{P}/tasks", json=task_body(observation=obs), headers=login("user1"))

    for ref, rule in {
        "models/cae": "walls_cae_not_cid",
        absent: "walls_cae_not_found",
        policy: "walls_cae_invalid",
        other_grid: "walls_cae_grid_mismatch",
        cae_bundle([ENV["rows"], ENV["cols"]], channels=None): "walls_cae_invalid",
        cae_bundle([ENV["rows"], ENV["cols"]], channels=[0]): "walls_cae_invalid",
    }.items():
        r = post(ref)
        assert r.status_code == 422, (ref, r.text)
        err = r.json()["detail"][0]
        assert (err["type"], err["loc"]) == (rule, ["body", "observation", "walls_embedding"])
    assert "6 x 6 grid, the task's is 8 x 8" in post(other_grid).text
    r = post(cae, size=16)  # the CAE's d is 8
    assert r.status_code == 422, r.text
    err = r.json()["detail"][0]
    assert err["type"] == "walls_cae_size_mismatch", err
    assert err["loc"] == ["body", "observation", "walls_embedding_size"]
    r = post(cae)
    assert r.status_code == 201, r.text
    spec = client.get(f"{P}/tasks/{r.json()['task_id']}").json()["spec"]
    assert spec["observation"]["walls_embedding"] == cae


def test_an_allocation_of_more_models_than_a_task_can_use_is_named(
    client: TestClient, login: Login
) -> None:
    """A task trains with at most 8 experts (trainingspec.MAX_EXPERTS): an allocation of 9 is
    refused naming expert_allocation and the rule, not with an error on a field never sent;
    a model description with control characters (PostgreSQL text cannot hold NUL) is a 422."""
    register(client, login, ["user1"], {"user3": {}, "user4": {}, "user5": {}})
    for i in range(9):
        _share(client, login, f"user{3 + i % 3}", ENV2, 0, f"expert {i}")
    r = client.post(f"{P}/models/requests", json={"domain": 0, "env": ENV2, "num_models": 9},
                    headers=login("user1"))
    assert r.status_code == 201, r.text
    body = task_body(expert_allocation=r.json()["alloc_id"])
    r = client.post(f"{P}/tasks", json=body, headers=login("user1"))
    assert r.status_code == 422, r.text
    err = r.json()["detail"][0]
    assert err["type"] == "allocation_too_many_experts"
    assert err["loc"] == ["body", "expert_allocation"]
    assert "at most 8 experts" in err["msg"]
    store = client.app.state.store  # type: ignore[attr-defined]
    cid = add_bundle(store, {"model.safetensors": weights_of("nul"),
                             "model.json": card_of(ENV2, "nul")})
    r = client.post(f"{P}/models", json={"cid": cid, "description": "evil\u0000desc",
                                         "domain": 0, "env": ENV2}, headers=login("user3"))
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "description"]
    assert "U+0000" in r.json()["detail"][0]["msg"]


def test_the_platform_memory_limit_counts_the_experts_nets(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """A belief-map expert on a walled 30 x 30 task holds a gain table per env in the worker
    (2 x 900 x 900 float32): 2,048 envs fit the 8 GiB limit alone (~0.7 GiB) and not with it
    (~14 GiB). Refused before anything is sent, naming the experts as the largest part."""
    register(client, login, ["user1"], {"user3": {}})
    store = client.app.state.store  # type: ignore[attr-defined]
    zoo = Path(__file__).resolve().parents[2] / "models" / "ch4-a3w3-belief-30x30"
    files = ("model.safetensors", "model.json")
    cid = add_bundle(store, {n: (zoo / n).read_bytes() for n in files})
    body = task_body(
        env={"rows": 30, "cols": 30, "agents": 3, "walls": [1, 3]},
        observation={"kind": "odmtl", "window": 7},
        algorithm={"ppo": {"num_envs": 2048}},
    )
    before = service.block_number()
    r = client.post(f"{P}/tasks", json=body | {"experts": [cid]}, headers=login("user1"))
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail["rule"] == "spec_exceeds_memory_limit"
    assert "largest part: experts" in detail["msg"]
    assert service.block_number() == before
    # an expert of QoS 0 is never loaded, so it costs nothing: beside a small one, it fits
    small = add_bundle(
        store, {"model.safetensors": weights_of("s"), "model.json": card_of(ENV2, "s")}
    )
    zero = body | {"experts": [{"model": cid, "qos": 0.0}, {"model": small, "qos": 1.0}]}
    r = client.post(f"{P}/tasks", json=zero, headers=login("user1"))
    assert r.status_code == 201, r.text


def test_an_expert_that_cannot_be_laid_on_the_task_grid_is_422_not_500(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """The adapter lays an expert's env on the task's grid with the expert's own team: 16
    agents do not fit a 4 x 4 one. The gateway runs the worker's card check
    (``expert_misfit``), so the task is refused before it is posted instead of collecting
    declines (or, as before, a 500 from the resource estimate)."""
    register(client, login, ["user1"], {"user3": {}})
    store = client.app.state.store  # type: ignore[attr-defined]
    crowd = add_bundle(store, {
        "model.safetensors": weights_of("c"),
        "model.json": card_of({"rows": 8, "cols": 8, "agents": 16, "max_steps": 50}, "c"),
    })
    before = service.block_number()
    body = task_body(env={"rows": 4, "cols": 4, "agents": 2, "max_steps": 50}, experts=[crowd])
    r = client.post(f"{P}/tasks", json=body, headers=login("user1"))
    assert r.status_code == 422, r.text
    issue = r.json()["detail"][0]
    assert issue["type"] == "expert_misfit" and issue["loc"] == ["body", "experts", 0]
    assert "16 agents and a target do not fit on 4x4" in issue["msg"] and crowd in issue["msg"]
    assert service.block_number() == before


def test_an_expert_reading_full_maps_of_another_grid_is_422(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """A DMTL expert reads whole maps of its own grid: it cannot serve a task on another
    grid, which every worker would decline. The gateway says so, naming the expert's index
    (the second here: the first, ODMTL, serves any grid)."""
    register(client, login, ["user1"], {"user3": {}})
    store = client.app.state.store  # type: ignore[attr-defined]
    env = {"rows": 8, "cols": 8, "agents": 2, "max_steps": 50}
    odmtl = add_bundle(store, {"model.safetensors": weights_of("o"),
                               "model.json": card_of(env, "o")})
    card = json.loads(card_of(env, "d")) | {"observation": {"kind": "dmtl"}}
    dmtl = add_bundle(store, {"model.safetensors": weights_of("d"),
                              "model.json": canonical_json(card)})
    before = service.block_number()
    body = task_body(env={"rows": 6, "cols": 6, "agents": 2, "max_steps": 50},
                     experts=[odmtl, dmtl])
    r = client.post(f"{P}/tasks", json=body, headers=login("user1"))
    assert r.status_code == 422, r.text
    issue = r.json()["detail"][0]
    assert issue["type"] == "expert_misfit" and issue["loc"] == ["body", "experts", 1]
    assert "DMTL reads full 8x8 maps" in issue["msg"]
    assert service.block_number() == before
    on_grid = task_body(env=env, experts=[odmtl, dmtl])  # on the experts' own grid: fine
    r = client.post(f"{P}/tasks", json=on_grid, headers=login("user1"))
    assert r.status_code == 201, r.text
