"""End-to-end over the REST API with the embedded chain: registration, task creation with the
spec in the content store, offers visible and equal to chain state, authorisation, validation."""

from __future__ import annotations

import json
from typing import Any

import pytest
from eth_account import Account
from fastapi.testclient import TestClient

from backend.api.routes import tasks as tasks_routes
from backend.chain.platform import OfferState, TaskStatus
from backend.services.chain import ChainService
from backend.settings import Settings
from backend.store.sealed import public_key_hex
from workers.mdrl.trainingspec import TrainingSpec

from .conftest import ENV, Login, P, addr, fund, register, task_body

WORKERS = {"user3": {"cpu_cores": 16}, "user4": {"cpu_cores": 8}, "user5": {"cpu_cores": 2}}


def test_create_task_offers_match_chain_and_spec_is_content_addressed(
    client: TestClient, login: Login, service: ChainService, offers_seen: list
) -> None:
    register(client, login, ["user1"], WORKERS)
    tmc = service.platform.tmc
    escrow_before = service.chain.balance(tmc.address)

    r = client.post(f"{P}/tasks", json=task_body(), headers=login("user1"))
    assert r.status_code == 201, r.text
    created = r.json()
    task_id = created["task_id"]
    assert len(created["offered"]) == 2
    assert set(created["offered"]) <= {addr(service, n) for n in WORKERS}
    # payment escrowed: reward per worker x num_workers
    assert service.chain.balance(tmc.address) - escrow_before == 2 * 10**15

    # the on-chain description is the CID of the stored spec, which holds the validated env
    on_chain = tmc.task(task_id)
    store = client.app.state.store  # type: ignore[attr-defined]
    spec = json.loads(store.get(created["spec_cid"]))
    assert spec["env"]["rows"] == ENV["rows"] and spec["budget"]["steps"] == 20_000
    assert spec["observation"]["kind"] == "odmtl" and spec["observation"]["window"] == 3
    # the stored document is the core type's canonical form (defaults filled in)
    assert TrainingSpec.from_dict(spec).to_dict() == spec

    detail = client.get(f"{P}/tasks/{task_id}").json()
    assert detail["description"] == created["spec_cid"]
    assert (detail["spec"], detail["spec_state"]) == (spec, "read")
    assert detail["requester"] == addr(service, "user1") == on_chain["requester"]
    assert detail["status"] == on_chain["status"].name.lower() == "open"
    assert int(detail["reward_wei"]) == on_chain["reward"] == 10**15
    assert detail["deadline"] == on_chain["deadline"]
    assert detail["num_workers"] == on_chain["num_workers"] == 2
    names = [e["name"] for e in detail["timeline"]]
    assert names == ["TaskAdded", "TaskOffered", "TaskOffered", "TaskAllocated"]
    offers = {o["worker"]: o for o in detail["offers"]}
    assert set(offers) == set(created["offered"])
    for worker, o in offers.items():
        chain_offer = tmc.offer(task_id, worker)
        assert chain_offer["state"] == OfferState.OFFERED and o["state"] == "offered"
        assert o["expiry"] == chain_offer["expiry"]
    # the indexer's hook saw each offer once
    assert sorted(offers_seen) == sorted((task_id, w) for w in created["offered"])

    # worker counters (assigned) follow WorkerInfoUpdated and equal the UMC's
    for name in WORKERS:
        w = client.get(f"{P}/workers/{addr(service, name)}").json()
        chain_c = service.platform.umc.counters(addr(service, name), 0, 0)
        assert w["counters"]["assigned"] == chain_c["assigned"]
    listed = client.get(f"{P}/tasks", params={"worker": created["offered"][0]}).json()
    assert [t["id"] for t in listed["data"]] == [task_id] and listed["count"] == 1


def _accept(service: ChainService, task_id: int, worker: str) -> None:
    with service.lock:
        service.platform.tmc.transact("acceptOffer", task_id, sender=worker)


def test_progress_review_and_cancel_act_only_for_the_right_address(
    client: TestClient, login: Login, service: ChainService, monkeypatch: pytest.MonkeyPatch
) -> None:
    register(client, login, ["user1", "user2"], WORKERS)
    task_id = client.post(
        f"{P}/tasks", json=task_body(num_workers=1), headers=login("user1")
    ).json()["task_id"]
    worker = client.get(f"{P}/tasks/{task_id}").json()["offers"][0]["worker"]
    name = next(n for n in WORKERS if addr(service, n) == worker)
    other = next(n for n in WORKERS if n != name)

    # another requester cannot cancel, allocate or review someone else's task
    for path, body in (
        ("cancel", None),
        ("allocate", None),
        ("reviews", {"worker": worker, "review": 5}),
    ):
        r = client.post(f"{P}/tasks/{task_id}/{path}", json=body, headers=login("user2"))
        assert r.status_code == 403, (path, r.text)
        assert r.json()["detail"]["rule"] == "not_task_requester"

    # progress only from an assigned worker: offered is not enough, accepted is
    point = {"step": 100, "success": 0.25, "time": 12.5, "cost": 3.0, "entropy": 1.2}
    r = client.post(f"{P}/tasks/{task_id}/progress", json=point, headers=login(name))
    assert r.status_code == 403 and r.json()["detail"]["rule"] == "not_assigned_worker"
    _accept(service, task_id, worker)
    client.app.state.indexer.poll()  # type: ignore[attr-defined]
    r = client.post(f"{P}/tasks/{task_id}/progress", json=point, headers=login(name))
    assert r.status_code == 201, r.text
    assert (
        client.post(f"{P}/tasks/{task_id}/progress", json=point, headers=login(name)).status_code
        == 409
    )
    # a bounded number of points per worker and task (each is a row)
    monkeypatch.setattr(tasks_routes, "MAX_PROGRESS_POINTS", 2)
    r = client.post(
        f"{P}/tasks/{task_id}/progress", json=point | {"step": 200}, headers=login(name)
    )
    assert r.status_code == 201, r.text
    r = client.post(
        f"{P}/tasks/{task_id}/progress", json=point | {"step": 300}, headers=login(name)
    )
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "progress_full"
    r = client.post(f"{P}/tasks/{task_id}/progress", json=point | {"step": 5}, headers=login(other))
    assert r.status_code == 403
    detail = client.get(f"{P}/tasks/{task_id}").json()
    assert [p["step"] for p in detail["progress"]] == [100, 200]
    assert detail["progress"][0]["extra"] == {"entropy": 1.2}

    # a task with an accepted worker cannot be cancelled (contract rule, named)
    r = client.post(f"{P}/tasks/{task_id}/cancel", headers=login("user1"))
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "tasks_has_accepted_workers"

    # submit, then the requester reviews (accept -> credited), status completes
    with service.lock:
        service.platform.tmc.submit_outcome(worker, task_id, "bafyoutcome")
    r = client.post(
        f"{P}/tasks/{task_id}/reviews", json={"worker": worker, "review": 4}, headers=login("user1")
    )
    assert r.status_code == 200, r.text
    detail = client.get(f"{P}/tasks/{task_id}").json()
    assert (
        detail["status"] == "completed" == service.platform.tmc.task(task_id)["status"].name.lower()
    )
    assert detail["outcomes"] == [
        {"worker": worker, "cid": "bafyoutcome", "review": 4, "accepted": True, "model_id": None}
    ]
    w = client.get(f"{P}/workers/{worker}").json()
    assert w["counters"]["rating_sum"] == 4 and w["rating"] == pytest.approx(0.8)
    # once its outcome is reviewed, the worker's curve is closed
    late = point | {"step": 200}
    r = client.post(f"{P}/tasks/{task_id}/progress", json=late, headers=login(name))
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "progress_closed"


def test_racing_progress_posts_stay_within_the_cap(
    client: TestClient, login: Login, service: ChainService, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Eight posts of distinct steps at once, one point below the cap: one lands, seven get
    ``progress_full``. The database sleeps after each count, so without the offer-row lock
    every post counts before any inserts and all eight land."""
    import threading
    import time

    from sqlalchemy import event

    register(client, login, ["user1"], WORKERS)
    task_id = client.post(
        f"{P}/tasks", json=task_body(num_workers=1), headers=login("user1")
    ).json()["task_id"]
    worker = client.get(f"{P}/tasks/{task_id}").json()["offers"][0]["worker"]
    name = next(n for n in WORKERS if addr(service, n) == worker)
    _accept(service, task_id, worker)
    client.app.state.indexer.poll()  # type: ignore[attr-defined]
    monkeypatch.setattr(tasks_routes, "MAX_PROGRESS_POINTS", 3)
    headers = login(name)
    url = f"{P}/tasks/{task_id}/progress"
    point = {"success": 0.5, "time": 10.0, "cost": 2.0}
    for step in (1, 2):
        r = client.post(url, json=point | {"step": step}, headers=headers)
        assert r.status_code == 201, r.text

    engine = client.app.state.sessions.kw["bind"]  # type: ignore[attr-defined]

    def slow_count(_conn: Any, _cursor: Any, statement: str, *_: Any) -> None:
        if "count(" in statement.lower() and "progress" in statement.lower():
            time.sleep(0.05)

    event.listen(engine, "after_cursor_execute", slow_count)
    start = threading.Barrier(8)
    codes: list[tuple[int, str]] = []

    def post(step: int) -> None:
        start.wait()
        r = client.post(url, json=point | {"step": step}, headers=headers)
        codes.append((r.status_code, r.json().get("detail", {}).get("rule", "")))

    try:
        threads = [threading.Thread(target=post, args=(10 + i,)) for i in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        event.remove(engine, "after_cursor_execute", slow_count)
    assert sorted(codes) == [(201, "")] + [(409, "progress_full")] * 7, codes
    assert len(client.get(f"{P}/tasks/{task_id}").json()["progress"]) == 3


def test_cancel_refunds_and_lists_by_status(
    client: TestClient, login: Login, service: ChainService, settings: Settings
) -> None:
    register(client, login, ["user1"], WORKERS)
    ids = [
        client.post(f"{P}/tasks", json=task_body(num_workers=1), headers=login("user1")).json()[
            "task_id"
        ]
        for _ in range(2)
    ]
    r = client.post(f"{P}/tasks/{ids[0]}/cancel", headers=login("user1"))
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "tasks_has_live_offers"
    with service.lock:  # once the acceptance window has passed, the offers are dead
        service.chain.advance_time(settings.accept_window_s + 1)
    r = client.post(f"{P}/tasks/{ids[0]}/cancel", headers=login("user1"))
    assert r.status_code == 200, r.text
    assert service.platform.tmc.task(ids[0])["status"] == TaskStatus.CANCELLED
    assert service.platform.tmc.call("credits", addr(service, "user1")) == 10**15
    cancelled = client.get(f"{P}/tasks", params={"status": "cancelled"}).json()
    opened = client.get(f"{P}/tasks", params={"status": "open"}).json()
    assert [t["id"] for t in cancelled["data"]] == [ids[0]]
    assert [t["id"] for t in opened["data"]] == [ids[1]]
    mine = client.get(f"{P}/tasks", params={"requester": addr(service, "user1").lower()}).json()
    assert mine["count"] == 2
    assert client.get(f"{P}/tasks", params={"requester": "0x1234"}).status_code == 422


def test_selection_goes_into_the_stored_spec(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """``selection`` is a spec field: stored with the spec the workers train (keep_best)."""
    register(client, login, ["user1"], WORKERS)
    body = task_body(selection={"keep_best": "time", "eval_every": 3})
    r = client.post(f"{P}/tasks", json=body, headers=login("user1"))
    assert r.status_code == 201, r.text
    store = client.app.state.store  # type: ignore[attr-defined]
    spec = TrainingSpec.from_json(store.get(r.json()["spec_cid"]))
    assert (spec.selection.keep_best, spec.selection.eval_every) == ("time", 3)


@pytest.mark.parametrize(
    ("change", "loc"),
    [
        ({"env": ENV | {"rows": 1}}, ["body", "env", "rows"]),
        ({"env": ENV | {"rows": 500}}, ["body", "env", "rows"]),
        ({"env": ENV | {"moves": 5}}, ["body", "env", "moves"]),
        ({"env": ENV | {"colour": "red"}}, ["body", "env", "colour"]),
        ({"env": ENV | {"reward": "dense"}}, ["body", "env", "reward"]),
        ({"env": ENV | {"agents": 64}}, ["body", "env", "agents"]),
        ({"env": ENV | {"walls": [3, 1]}}, ["body", "env", "walls"]),
        ({"observation": {"kind": "xmtl", "window": 3}}, ["body", "observation", "kind"]),
        ({"observation": {"kind": "odmtl", "window": 9}}, ["body", "observation", "window"]),
        ({"observation": {"kind": "odmtl", "window": 4}}, ["body", "observation", "window"]),
        ({"budget": {"steps": 10**12, "minutes": 10}}, ["body", "budget", "steps"]),
        ({"budget": {"steps": 20_000, "minutes": 0}}, ["body", "budget", "minutes"]),
        ({"budget": {}}, ["body", "budget"]),
        ({"env": ENV | {"intensity": 1e308}}, ["body", "env", "intensity"]),
        ({"env": ENV | {"intensity": float("nan")}}, ["body", "env", "intensity"]),
        ({"env": ENV | {"intensity": float("inf")}}, ["body", "env", "intensity"]),
        (
            {"env": ENV | {"intensity": {"kind": "uniform", "values": [1e9, 1e8]}}},
            ["body", "env", "intensity", "values"],
        ),
        ({"env": ENV | {"walls": [0, 9]}}, ["body", "env", "walls"]),
        # walls that leave 15 agents no room: no worker's env could lay them out
        (
            {"env": {"rows": 4, "cols": 4, "agents": 15, "moves": 8, "walls": [2, 3]}},
            ["body", "env", "walls"],
        ),
        (
            {"algorithm": {"ppo": {"anneal_lr": True}}, "budget": {"minutes": 10}},
            ["body", "algorithm", "ppo", "anneal_lr"],
        ),
        # CMTL's joint actions beyond what a worker's observer is built for (5**16)
        (
            {"env": {"rows": 10, "cols": 10, "agents": 16}, "observation": {"kind": "cmtl"}},
            ["body", "observation", "kind"],
        ),
        ({"algorithm": {"preset": "nope"}}, ["body", "algorithm", "preset"]),
        ({"algorithm": {"ppo": {"num_envs": 0}}}, ["body", "algorithm", "ppo", "num_envs"]),
        ({"experts": ["../../etc/passwd"]}, ["body", "experts", 0]),
        ({"selection": {"keep_best": "fastest"}}, ["body", "selection", "keep_best"]),
        ({"selection": {"eval_every": 2}}, ["body", "selection", "eval_every"]),
        ({"ppo": {"num_envs": 4}}, ["body", "ppo"]),
        ({"num_workers": 17}, ["body", "num_workers"]),
        ({"payment_wei": -1}, ["body", "payment_wei"]),
        ({"payment_wei": 2**96}, ["body", "payment_wei"]),
        ({"min_reputation": 1.5}, ["body", "min_reputation"]),
        ({"domain": 256}, ["body", "domain"]),
        ({"deadline_s": 5}, ["body", "deadline_s"]),
    ],
)
def test_malformed_task_is_422_naming_the_field(
    client: TestClient, login: Login, service: ChainService, change: dict[str, Any], loc: list
) -> None:
    register(client, login, ["user1"], {})
    before = service.block_number()
    # json.dumps writes NaN/Infinity tokens (httpx refuses to), as a hostile client may
    headers = login("user1") | {"content-type": "application/json"}
    r = client.post(f"{P}/tasks", content=json.dumps(task_body(**change)), headers=headers)
    assert r.status_code == 422, r.text
    assert loc in [d["loc"][: len(loc)] for d in r.json()["detail"]], r.json()
    assert service.block_number() == before  # nothing was sent


@pytest.mark.parametrize(
    ("change", "rule"),
    [
        # CMTL with 8 agents: a joint action space of 5**8, masks of it per sample (~13 GiB;
        # 9 agents and more are refused by the spec's own rule, observation.kind)
        (
            {"env": {"rows": 10, "cols": 10, "agents": 8}, "observation": {"kind": "cmtl"}},
            "spec_exceeds_memory_limit",
        ),
        # a huge batch on the largest grid: every field in bounds, the product is not
        (
            {
                "env": {"rows": 64, "cols": 64, "agents": 16},
                "observation": {"kind": "dmtl"},
                "algorithm": {"ppo": {"num_envs": 4096, "horizon": 1_000_000}},
            },
            "spec_exceeds_memory_limit",
        ),
        # a week on 16 workers
        (
            {"budget": {"minutes": 10_080}, "num_workers": 16},
            "spec_exceeds_worker_hours_limit",
        ),
    ],
)
def test_a_spec_beyond_the_platform_limits_is_422_naming_the_limit(
    client: TestClient, login: Login, service: ChainService, change: dict[str, Any], rule: str
) -> None:
    register(client, login, ["user1"], {})
    before = service.block_number()
    r = client.post(f"{P}/tasks", json=task_body(**change), headers=login("user1"))
    assert r.status_code == 422, r.text
    assert r.json()["detail"]["rule"] == rule, r.json()
    assert service.block_number() == before  # nothing was sent


def test_writes_need_a_token_and_a_registered_requester(
    client: TestClient, login: Login, service: ChainService
) -> None:
    store = client.app.state.store  # type: ignore[attr-defined]
    blocks = store.blocks()
    assert client.post(f"{P}/tasks", json=task_body()).status_code == 401
    r = client.post(f"{P}/tasks", json=task_body(), headers=login("user6"))  # not a requester
    assert r.status_code == 403 and r.json()["detail"]["rule"] == "tasks_not_requester"
    assert store.blocks() == blocks  # refused before the spec is stored
    client.post(f"{P}/users/requesters", headers=login("user6"))
    r = client.post(f"{P}/users/requesters", headers=login("user6"))
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "users_already_registered"


def test_sign_locally_then_relay(client: TestClient, service: ChainService, settings: Any) -> None:
    """A user whose key the gateway does not hold gets the unsigned tx (409), signs it, relays it;
    a transaction signed by someone else is refused."""
    from backend.auth import DemoKeys, bearer_headers

    me, stranger = Account.create(), Account.create()
    fund(service, me.address)  # gas for the new account
    own = DemoKeys(settings)  # the client's keys, not the gateway's
    own.add("me", me)
    headers = dict(bearer_headers(own.sign_in(client, "me")))

    r = client.post(f"{P}/users/requesters", headers=headers)
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "sign_locally"
    unsigned = r.json()["detail"]["tx"]
    assert unsigned["from"] == me.address and unsigned["to"] == service.platform.umc.address
    unsigned.pop("from")
    forged = "0x" + bytes(stranger.sign_transaction(unsigned).raw_transaction).hex()
    r = client.post(f"{P}/tx", json={"raw": forged}, headers=headers)
    assert r.status_code == 403 and r.json()["detail"]["rule"] == "tx_sender_mismatch"
    assert not service.platform.umc.call("isRequester", me.address)
    # signed for another chain (EIP-155 replay from elsewhere), or for none (pre-EIP-155)
    legacy = {k: v for k, v in unsigned.items() if not k.startswith("max") and k != "type"}
    legacy["gasPrice"] = unsigned["maxFeePerGas"]
    for other in (
        me.sign_transaction({**unsigned, "chainId": 1}),
        me.sign_transaction({**legacy, "chainId": 5}),
        me.sign_transaction({k: v for k, v in legacy.items() if k != "chainId"}),
    ):
        r = client.post(
            f"{P}/tx", json={"raw": "0x" + bytes(other.raw_transaction).hex()}, headers=headers
        )
        assert r.status_code == 422 and r.json()["detail"]["rule"] == "tx_invalid", r.text
        assert "chain" in r.json()["detail"]["msg"]
        rpc = client.post(
            "/rpc",
            json={
                "jsonrpc": "2.0",
                "id": 1,
                "method": "eth_sendRawTransaction",
                "params": ["0x" + bytes(other.raw_transaction).hex()],
            },
        )
        assert rpc.json()["error"]["code"] == -32000 and "chain" in rpc.json()["error"]["message"]
    assert not service.platform.umc.call("isRequester", me.address)

    raw = "0x" + bytes(me.sign_transaction(unsigned).raw_transaction).hex()
    r = client.post(f"{P}/tx", json={"raw": raw}, headers=headers)
    assert r.status_code == 200, r.text
    assert [e["name"] for e in r.json()["events"]] == ["RequesterStatusUpdated", "RequesterAdded"]
    assert service.platform.umc.call("isRequester", me.address)
    # a relayed transaction that reverts is named by the contract's error, as on own routes
    again = {**unsigned, "nonce": unsigned["nonce"] + 1}
    raw = "0x" + bytes(me.sign_transaction(again).raw_transaction).hex()
    r = client.post(f"{P}/tx", json={"raw": raw}, headers=headers)
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "users_already_registered"
    assert client.post(f"{P}/tx", json={"raw": "0x12"}, headers=headers).status_code == 422


def test_outcome_key_must_be_the_requesters(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """A task's outcome is sealed to its requester only: a key of another address is a 422
    naming ``outcome_key``, nothing sent; the requester's own key is stored in the spec."""
    register(client, login, ["user1"], {})
    assert service.demo_keys is not None
    other = public_key_hex(bytes(Account.create().key))
    before = service.block_number()
    r = client.post(f"{P}/tasks", json=task_body(outcome_key=other), headers=login("user1"))
    assert r.status_code == 422, r.text
    (err,) = r.json()["detail"]
    assert err["loc"] == ["body", "outcome_key"] and err["type"] == "outcome_key_not_requester"
    assert service.block_number() == before
    own = public_key_hex(bytes(service.demo_keys.account("user1").key))
    r = client.post(f"{P}/tasks", json=task_body(outcome_key=own), headers=login("user1"))
    assert r.status_code == 201, r.text
    spec = client.get(f"{P}/tasks/{r.json()['task_id']}").json()["spec"]
    assert spec["outcome_key"] == own.lower()


@pytest.mark.parametrize("field", ["success", "time", "cost"])
@pytest.mark.parametrize("value", ["NaN", "Infinity", "-Infinity"])
def test_a_progress_point_names_a_non_finite_number(field: str, value: str) -> None:
    from pydantic import ValidationError

    from backend.schemas.tasks import ProgressCreate

    with pytest.raises(ValidationError) as bad:
        ProgressCreate.model_validate_json(f'{{"step": 1, "{field}": {value}}}')
    [err] = bad.value.errors()
    assert (err["loc"], err["type"]) == ((field,), "finite_number")


def test_a_posted_task_whose_allocation_fails_is_answered_with_its_id(
    client: TestClient, login: Login, service: ChainService, monkeypatch: pytest.MonkeyPatch
) -> None:
    """addTask mined, allocateTask failed (a node that does not mine in time, a gateway
    stopped between the two): the answer names the task, so the client allocates it again
    instead of posting (and paying for) a second task (durability audit of 2026-12-03, F5)."""
    register(client, login, ["user1"], WORKERS)
    real_send = ChainService.send

    def send(self: ChainService, sender: str, handle: Any, fn: str, *args: Any, **kw: Any) -> Any:
        if fn == "allocateTask":
            raise TimeoutError("the allocation's receipt did not come in time")
        return real_send(self, sender, handle, fn, *args, **kw)

    monkeypatch.setattr(ChainService, "send", send)
    r = client.post(f"{P}/tasks", json=task_body(), headers=login("user1"))
    assert r.status_code == 201, r.text
    created = r.json()
    assert created["offered"] == [] and len(created["tx_hashes"]) == 1
    assert "allocation" in created["allocation_error"]
    assert "Traceback" not in created["allocation_error"]
    task_id = created["task_id"]
    assert service.platform.tmc.task(task_id)["offer_count"] == 0
    monkeypatch.setattr(ChainService, "send", real_send)
    r = client.post(f"{P}/tasks/{task_id}/allocate", headers=login("user1"))
    assert r.status_code == 200, r.text
    assert service.platform.tmc.task(task_id)["offer_count"] == 2
    assert service.platform.tmc.call("taskCount") == task_id  # one task, not two
