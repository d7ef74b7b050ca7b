"""The model page's API (issue 10): chain values in human units, the producing task from the
chain's outcome record, experts linked to their models, the card's curve and held-out figures
as the card says them, and a hostile card that leaves the page with less on it, never a 500;
the task list's environments."""

from __future__ import annotations

import json
from typing import Any

from fastapi.testclient import TestClient

from backend.api.routes.tasks import task_env
from backend.db import models as m
from backend.schemas.cards import CardView
from backend.schemas.common import wei_to_eth
from backend.services.chain import ChainService
from backend.services.specs import validate_env
from backend.store.bundle import add_bundle
from drlaas.commands.client.models import hub_lines
from drlaas.commands.client.tasks import env_summary

from .conftest import ENV, Login, P, addr, register, task_body
from .test_models import weights_of

WORKERS = {"user3": {"cpu_cores": 16}, "user4": {"cpu_cores": 8}}
POINTS = [
    {"step": 4096, "wall_s": 1.5, "success": 0.25, "time": 61.0, "cost": 90.5},
    {"step": 8192, "wall_s": 3.0, "success": 0.75, "time": 20.25, "cost": 30.0},
]
HELDOUT = {
    "episodes": 1000,
    "seed": 20261124,
    "poisson": {"success": 0.999, "time": 5.5, "time_ci": [5.2, 5.8], "cost": 6.5,
                "cost_ci": [6.25, 6.75], "oracle_time": 4.0,
                "baselines": {"bayes": {"success": 1.0, "time": 4.5, "time_ci": [4.25, 4.75],
                                        "cost": 5.0, "cost_ci": [4.75, 5.25]},
                              "random": {"success": 2.0, "time": 50.0}}},  # random: invalid
    "expected": {"success": 1.0, "time": 5.0, "time_ci": [4.8, 5.2], "cost": 6.0,
                 "cost_ci": [5.75, 6.25], "oracle_time": 4.0},
}  # fmt: skip


def card_bytes(env: dict, **sections: Any) -> bytes:
    card = {"format": "drlaas-model/1", "env": validate_env(env).to_dict(),
            "observation": {"kind": "odmtl", "window": 3}, **sections}
    return json.dumps(card).encode()  # NaN allowed on purpose: a card is anyone's file


def share(client: TestClient, login: Login, name: str, card: bytes, text: str) -> dict:
    store = client.app.state.store  # type: ignore[attr-defined]
    cid = add_bundle(store, {"model.safetensors": weights_of(text, 100), "model.json": card})
    body = {"cid": cid, "description": text, "env": json.loads(card)["env"]}
    r = client.post(f"{P}/models", json=body, headers=login(name))
    assert r.status_code == 201, r.text
    return r.json()


def index_row(client: TestClient, cls: Any, key: Any) -> Any:
    with client.app.state.sessions() as s:  # type: ignore[attr-defined]
        return s.get(cls, key)


def test_model_page_links_task_experts_and_reads_the_card(
    client: TestClient, login: Login, service: ChainService
) -> None:
    register(client, login, ["user1"], WORKERS)
    expert = share(client, login, "user4", card_bytes(ENV), "an expert")
    payment = 1_234_567_890_123_456  # wei per worker
    body = task_body(num_workers=1, payment_wei=payment, experts=[expert["cid"]])
    r = client.post(f"{P}/tasks", json=body, headers=login("user1"))
    assert r.status_code == 201, r.text
    task_id, [owner] = r.json()["task_id"], r.json()["offered"]

    # the task list shows the spec's environment and the reward in ETH, exactly
    [listed] = [t for t in client.get(f"{P}/tasks").json()["data"] if t["id"] == task_id]
    assert listed["reward_wei"] == str(payment) and listed["reward_eth"] == "0.001234567890123456"
    assert listed["env"] == {
        "rows": 8, "cols": 8, "agents": 2, "walls": [0, 0], "moves": 4,
        "intensity": {"kind": "fixed", "values": [1e9]},
    }  # fmt: skip
    assert client.get(f"{P}/tasks/{task_id}").json()["env"] == listed["env"]
    assert env_summary(listed) == "8x8 2 agents 0 walls 4 moves I=1e+09"  # `drlaas task list`

    # the worker's outcome: a card with a curve, held-out figures and its experts
    card = card_bytes(
        ENV,
        curve={"x": "env_steps", "updates": 2, "points": POINTS},
        zoo={"name": "hub-test", "heldout": HELDOUT},
        training={"env_steps": 8192, "updates": 2, "wall_time_s": 3.0,
                  "experts": {"method": "DC", "experts": [
                      {"ref": expert["cid"], "episodes": 12, "decisions": 300, "followed": 250,
                       "agreed": 200, "selection_probability": 1.0},
                      {"ref": "runs/local-expert", "decisions": 2, "followed": 3}],
                      "review": {"episodes": 100, "seed": 1, "oracle_time": 9.6, "experts": [
                          {"ref": expert["cid"], "success": 1.0, "time": 12.0, "cost": 30.0,
                           "time_vs_oracle": 1.25, "suggested_review": 4},
                          {"ref": "runs/local-expert", "success": 1.0, "time": 9.0,
                           "suggested_review": 9}]}}},
        metrics={"eval_success": 0.5, "eval_time": 30.0, "eval_cost": 40.0, "loss": 0.1},
    )  # fmt: skip
    store = client.app.state.store  # type: ignore[attr-defined]
    cid = add_bundle(store, {"model.safetensors": weights_of("o", 1000), "model.json": card})
    with service.lock:
        service.platform.tmc.transact("acceptOffer", task_id, sender=owner)
        service.platform.tmc.submit_outcome(owner, task_id, cid)
    client.app.state.indexer.poll()  # type: ignore[attr-defined]
    review = {"worker": owner, "review": 4}
    r = client.post(f"{P}/tasks/{task_id}/reviews", json=review, headers=login("user1"))
    assert r.status_code == 200, r.text
    names = {addr(service, n): n for n in WORKERS}
    shared = client.post(
        f"{P}/models", json={"cid": cid, "env": ENV}, headers=login(names[owner])
    ).json()

    price = 1_234_567_890_123  # wei per model
    r = client.post(
        f"{P}/models/requests",
        json={"env": ENV, "num_models": 2, "price_wei": price},
        headers=login("user1"),
    )
    assert r.status_code == 201, r.text
    alloc_id = r.json()["alloc_id"]

    d = client.get(f"{P}/models/{shared['id']}").json()
    assert d["produced_by"] == {
        "task_id": task_id, "worker": owner, "review": 4, "accepted": True, "source": "chain",
    }  # fmt: skip
    # each expert with what the card says the run did with it (followed > decisions: none)
    assert d["experts"] == [
        {"ref": expert["cid"], "cid": expert["cid"], "model_id": expert["id"],
         "source": "task_spec", "usage": {
             "episodes": 12, "decisions": 300, "followed": 250, "agreed": 200,
             "selection_probability": 1.0,
             # the worker's trial after the run (a suggestion out of 0-5: dropped)
             "trial": {"episodes": 100, "success": 1.0, "time": 12.0, "time_vs_oracle": 1.25,
                       "suggested_review": 4}}},
        {"ref": "runs/local-expert", "cid": None, "model_id": None, "source": "card",
         "usage": None},
    ]  # fmt: skip
    assert d["name"] == "hub-test" and d["curve"] == POINTS and d["curve_updates"] == 2
    assert d["trained"] == {"env_steps": 8192, "updates": 2, "wall_time_s": 3.0,
                            "selected_by": None}
    assert d["final_eval"] == {"success": 0.5, "time": 30.0, "cost": 40.0}
    assert d["env_spec"] == validate_env(ENV).to_dict()
    held = d["heldout"]
    assert held["episodes"] == 1000 and held["seed"] == 20261124
    assert [f["reading_model"] for f in held["readings"]] == ["poisson", "expected"]
    for f in held["readings"]:
        claimed = HELDOUT[f["reading_model"]]
        for key in ("success", "time", "time_ci", "cost", "cost_ci", "oracle_time"):
            assert f[key] == claimed[key]
        assert f["time_vs_oracle"] == claimed["time"] / claimed["oracle_time"]
    bayes = HELDOUT["poisson"]["baselines"]["bayes"]  # type: ignore[index]
    assert held["readings"][0]["baselines"] == [
        {"name": "bayes", **bayes, "time_vs_oracle": 4.5 / 4.0}
    ]  # the invalid random figures are left out
    assert held["readings"][1]["baselines"] == []

    # chain values: exact conversions of the indexed fixed-point integers and wei
    [req] = d["requests"]
    assoc = index_row(client, m.AllocatedModel, (alloc_id, shared["id"]))
    assert req["alloc_id"] == alloc_id and req["requester"] == addr(service, "user1")
    assert req["qos"] == assoc.qos / 1_000_000 and 0 < req["qos"] <= 1
    assert req["price_wei"] == str(price) and req["price_eth"] == "0.000001234567890123"
    row = index_row(client, m.ModelRow, shared["id"])
    assert d["reputation"] == row.reputation / 1_000_000

    # the CLI's `drlaas model show` prints the same figures
    lines = hub_lines(d)
    assert f"produced by task {task_id} (worker {owner}; the chain's outcome record)" in lines
    assert f"expert {expert['cid']} (model {expert['id']}; from the task spec)" in lines
    assert (
        "held-out (1000 episodes, poisson readings): success 99.9%, time 5.50 (oracle 4.00), "
        "cost 6.50" in lines
    )
    # the card's own final evaluation (what the web page shows), labelled not held out; the
    # curve's last point is training episodes, not an evaluation
    final = d["final_eval"]
    assert any(ln.startswith("final evaluation (the run's own episodes, not held out): "
                             f"success {100 * final['success']:.1f}%") for ln in lines), lines
    assert any("its last point (training episodes that ended then)" in ln for ln in lines)

    # the expert was no task's outcome: no producing task; its card has no curve
    e = client.get(f"{P}/models/{expert['id']}").json()
    assert e["produced_by"] is None and e["curve"] == [] and e["heldout"] is None


def test_a_hostile_card_leaves_out_what_does_not_validate(client: TestClient, login: Login) -> None:
    register(client, login, [], {"user3": {}})
    bad = card_bytes(
        ENV,
        curve={"updates": "many", "points": [
            POINTS[1], {"step": "x"}, {"step": 5, "success": 7}, {"step": -1}, POINTS[0], "p",
        ]},
        zoo={"name": "<b>" * 50, "heldout": {
            "episodes": 10, "poisson": {"success": "high"}, "expected": HELDOUT["expected"],
        }},
        training={"experts": {"experts": [
            {"ref": 5}, {"ref": "ok-name", "episodes": float("inf")}, "str", {"ref": ""},
            {"ref": "ok-name", "episodes": 3},  # a second record of a ref: the first counts
        ]}, "env_steps": 100, "selected": {"by": "<b>best</b>", "update": "x"}},
        metrics={"eval_success": float("nan"), "eval_time": float("inf")},
        model="<script>",
    )  # fmt: skip
    a = share(client, login, "user3", bad, "hostile")
    d = client.get(f"{P}/models/{a['id']}").json()
    assert d["curve"] == POINTS and d["curve_updates"] is None  # sorted, bad points dropped
    assert d["name"] is None and d["kind"] is None
    assert [f["reading_model"] for f in d["heldout"]["readings"]] == ["expected"]
    assert [(x["ref"], x["usage"]) for x in d["experts"]] == [("ok-name", None)]
    # training.selected with an unknown rule: not a kept policy; the rest of `trained` stays
    assert d["trained"] == {"env_steps": 100, "updates": None, "wall_time_s": None,
                            "selected_by": None}
    assert d["final_eval"] is None
    assert d["card"]["metrics"] == {"eval_success": None, "eval_time": None}  # JSON has no NaN

    too_long = card_bytes(ENV, curve={"points": [POINTS[0]] * 1001})
    deep = card_bytes(ENV, x=json.loads("[" * 40 + "]" * 40))
    for card in (too_long, deep):
        model = share(client, login, "user3", card, f"{len(card)} bytes")
        r = client.get(f"{P}/models/{model['id']}")
        assert r.status_code == 200, r.text
        assert r.json()["curve"] == []
    assert r.json()["card"] is None  # deeper than the gateway reads


def test_task_env_parses_with_the_core_rules() -> None:
    assert task_env({"rows": 6, "cols": 7, "agents": 1, "walls": [1, 2]}) == {
        "rows": 6, "cols": 7, "agents": 1, "walls": [1, 2], "moves": 4,
        "intensity": {"kind": "fixed", "values": [1e9]},
    }  # fmt: skip
    for hostile in (None, "10x10", {"rows": 1}, {"rows": 6, "cols": 6, "walls": [9, 9]}, [1]):
        assert task_env(hostile) is None


def test_wei_to_eth_is_exact() -> None:
    assert wei_to_eth(0) == "0" and wei_to_eth(10**18) == "1"
    assert wei_to_eth("1") == "0." + "0" * 17 + "1"
    assert wei_to_eth(10**28 + 5 * 10**15) == "10000000000.005"


def test_card_text_with_invisible_format_characters_is_left_out() -> None:
    """A right-to-left override in an expert ref reordered the page's own label after it
    (a card's word posed as "named by the task's spec"; audit of 2026-12-03, F8)."""
    card = {
        "zoo": {"name": "expert \u202eceps"},
        "training": {"experts": {"experts": [
            {"ref": "a local model \u202eceps s'ksat eht yb deman", "episodes": 3},
            {"ref": "zero\u200bwidth"},
            {"ref": "models/a1w0", "episodes": 2},
        ]}},
    }  # fmt: skip
    view = CardView.from_card(card)
    assert view.name is None
    assert view.expert_refs == ["models/a1w0"]
    assert list(view.expert_usage) == ["models/a1w0"]
    plain = "A3W3 route, 30 x 30"
    assert CardView.from_card({"zoo": {"name": plain}}).name == plain
