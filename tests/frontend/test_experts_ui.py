"""Experts (MEDC) in the web UI: the submit form names expert CIDs or buys K from the MMC
(POST /models/requests, then the task names the allocation), refuses a bad CID on its field, and
the task page lists the experts with the requester's review (POST /models/requests/{id}/reviews)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from fastapi import Request

from backend.schemas.tasks import TaskExpertPublic
from tests.frontend.conftest import LiveServer, screenshot, sign_in_as_alice
from tests.frontend.fake_api import ALICE, W1, W2, W3, FakeState, make_fake_app

expect = pytest.importorskip("playwright.sync_api", reason="pip install playwright").expect

CID_A = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
CID_B = "bafkreihdwdcefgh4dqkjv67uzcmw7ojee6xedzdetojuzjevtenxquvyku"


@pytest.fixture(scope="module")
def fake_mmc() -> Iterator[tuple[LiveServer, FakeState, list]]:
    """The fake gateway plus the two MMC routes the expert UI calls (recorded in ``calls``)."""
    state, calls = FakeState(), []
    app = make_fake_app(state)

    @app.post("/api/models/requests", status_code=201)
    async def request_models(request: Request) -> dict:
        calls.append(("request", await request.json()))
        return {"alloc_id": 9, "models": [{"id": 2, "cid": CID_B, "qos": 0.625}]}

    @app.post("/api/models/requests/{alloc_id}/reviews")
    async def review(alloc_id: int, request: Request) -> dict:
        calls.append(("review", alloc_id, await request.json()))
        return {"tx_hash": "0x" + "1" * 64, "block_number": 1, "status": 1, "events": []}

    routes = app.router.routes  # before the UI's catch-all mount (added last)
    routes[:] = [*routes[:-3], *routes[-2:], routes[-3]]
    with LiveServer(app) as server:
        yield server, state, calls


@pytest.fixture
def mmc(fake_mmc: tuple[LiveServer, FakeState, list]) -> tuple[LiveServer, FakeState, list]:
    fake_mmc[1].reset()
    fake_mmc[2].clear()
    return fake_mmc


def small_task(page: Any) -> None:
    page.fill("#f-env-agents", "2")
    page.fill("#f-env-rows", "6")
    page.fill("#f-env-cols", "6")


def test_the_form_names_experts_or_buys_them(page: Any, mmc: Any) -> None:
    server, state, calls = mmc
    page.goto(f"{server.url}/submit")
    sign_in_as_alice(page)
    small_task(page)
    page.fill("#f-experts", f"{CID_A}, oracle")
    page.click("#submit-task")
    expect(page.locator("#err-experts")).to_contain_text("oracle is not a model CID")
    page.fill("#f-experts", CID_A)
    page.fill("#f-experts_from_mmc", "2")
    page.click("#submit-task")
    expect(page.locator("#err-experts_from_mmc")).to_contain_text("not both")
    assert state.posted_tasks == [] and calls == []

    page.fill("#f-experts_from_mmc", "0")
    page.fill("#f-algorithm-demonstration-rate", "0.3")
    page.click("#submit-task")
    expect(page.locator("#submit-result")).to_contain_text("created")
    assert state.posted_tasks[-1]["experts"] == [CID_A]
    assert state.posted_tasks[-1]["algorithm"] == {"demonstration": {"rate": 0.3}}
    assert "expert_allocation" not in state.posted_tasks[-1] and calls == []

    page.fill("#f-experts", "")
    page.fill("#f-algorithm-demonstration-rate", "")  # this fake cannot resolve allocations
    page.fill("#f-experts_from_mmc", "1")
    page.click("#submit-task")
    expect(page.locator("#bought-experts")).to_contain_text("Allocation #9")
    expect(page.locator("#bought-experts")).to_contain_text(CID_B)
    assert calls == [
        ("request", {"domain": 0, "env": state.posted_tasks[-1]["env"], "num_models": 1})
    ]
    assert state.posted_tasks[-1]["expert_allocation"] == 9
    assert "experts" not in state.posted_tasks[-1]


def test_the_task_page_lists_experts_and_takes_the_review(page: Any, mmc: Any) -> None:
    server, state, calls = mmc
    tid = next(t["id"] for t in state.tasks if t["requester"] == ALICE)
    state.task(tid)["experts"] = [
        {
            "cid": CID_A,
            "qos": 0.625,
            "model_id": 2,
            "reputation": 0.0,
            "alloc_id": 9,
            "review": None,
            # the worker's trial of it in its outcome card (GET /tasks/{id}: backend/api/cards.py)
            "trials": [{"worker": W1, "episodes": 100, "success": 0.98, "time": 13.7,
                        "time_vs_oracle": 1.43, "suggested_review": 3}],
            "suggested_review": 3,  # the trials' together (the gateway's computed field)
        },
        {
            "cid": CID_B,
            "qos": None,
            "model_id": None,
            "reputation": None,
            "alloc_id": None,
            "review": None,
        },
    ]
    page.goto(f"{server.url}/tasks/{tid}")
    sign_in_as_alice(page)
    rows = page.locator("#experts-table tbody tr")
    expect(rows).to_have_count(2)
    expect(rows.nth(1)).to_contain_text("named by CID")
    expect(rows.nth(1).locator("button")).to_have_count(0)  # no allocation: nothing to review
    expect(rows.nth(1).locator(".trial")).to_have_text("not measured")
    expect(rows.nth(0)).to_contain_text("#9")
    expect(rows.nth(0).locator(".trial")).to_have_text("13.7 steps (1.43× oracle), suggests 3/5")
    expect(rows.nth(0).locator("select")).to_have_value("3")  # the suggestion, preselected
    screenshot(page, "task-experts")
    rows.nth(0).locator("button").click()
    expect(page.locator("#task-message")).to_contain_text("Expert review: sent")
    assert calls == [("review", 9, {"model_id": 2, "review": 3})]


def test_the_task_page_shows_every_workers_trial_and_starts_at_their_middle_review(
    page: Any, mmc: Any
) -> None:
    """A task with several workers has a trial per outcome: each is listed with its worker, and
    the review control starts at the review they suggest together (``suggested_review``, the
    gateway's middle one, not whichever outcome came first)."""
    server, state, _ = mmc
    tid = next(t["id"] for t in state.tasks if t["requester"] == ALICE)

    def trial(worker: str, time: float, suggested: int) -> dict:
        return {"worker": worker, "episodes": 100, "success": 1.0, "time": time,
                "time_vs_oracle": round(time / 9.6, 2), "suggested_review": suggested}

    state.task(tid)["experts"] = [
        {"cid": CID_A, "qos": None, "model_id": 2, "reputation": 0.5, "alloc_id": 9,
         "review": None, "trials": [trial(W1, 48.0, 1), trial(W2, 12.0, 4), trial(W3, 10.0, 5)]},
        {"cid": CID_B, "qos": None, "model_id": 3, "reputation": 0.5, "alloc_id": 9,
         "review": None, "trials": [trial(W1, 24.0, 2), trial(W2, 12.0, 4)]},
    ]
    for x in state.task(tid)["experts"]:  # as the gateway serves them
        x["suggested_review"] = TaskExpertPublic(**x).suggested_review
    page.goto(f"{server.url}/tasks/{tid}")
    sign_in_as_alice(page)
    rows = page.locator("#experts-table tbody tr")
    expect(rows).to_have_count(2)
    lines = rows.nth(0).locator(".trial-line")
    expect(lines).to_have_count(3)
    expect(lines.nth(0)).to_have_attribute("data-worker", W1)
    expect(lines.nth(0)).to_have_text(f"{W1[:6]}…{W1[-4:]}: 48 steps (5× oracle), suggests 1/5")
    expect(lines.nth(2)).to_contain_text("suggests 5/5")
    expect(rows.nth(0).locator("select")).to_have_value("4")  # median of 1, 4, 5
    expect(rows.nth(1).locator(".trial-line")).to_have_count(2)
    expect(rows.nth(1).locator("select")).to_have_value("2")  # lower middle of 2, 4
    screenshot(page, "task-experts-trials")


def test_the_form_sets_the_walls_cae_and_the_expert_credit(page: Any, mmc: Any) -> None:
    """observation.walls_embedding (a CAE by CID, with its d) and
    algorithm.demonstration.credit: each refused on its field where it cannot apply, and sent
    in the body where it can."""
    server, state, _ = mmc
    page.goto(f"{server.url}/submit")
    sign_in_as_alice(page)
    small_task(page)
    page.fill("#f-observation-walls_embedding", "runs/cae")
    page.fill("#f-observation-walls_embedding_size", "64")
    page.select_option("#f-algorithm-demonstration-credit", "true")
    page.click("#submit-task")
    expect(page.locator("#err-observation-walls_embedding")).to_contain_text("not a model CID")
    expect(page.locator("#err-algorithm-demonstration-credit")).to_contain_text("only with experts")
    page.fill("#f-observation-walls_embedding", "")
    page.click("#submit-task")
    expect(page.locator("#err-observation-walls_embedding_size")).to_contain_text(
        "only with a walls autoencoder"
    )
    assert state.posted_tasks == []

    page.fill("#f-env-walls_max", "2")
    page.fill("#f-observation-walls_embedding", CID_B)
    page.fill("#f-experts", CID_A)
    page.click("#submit-task")
    expect(page.locator("#submit-result")).to_contain_text("created")
    body = state.posted_tasks[-1]
    assert body["observation"] == {
        "kind": "odmtl",
        "window": 3,
        "walls_embedding": CID_B,
        "walls_embedding_size": 64,
    }
    assert body["algorithm"] == {"demonstration": {"credit": True}}
    assert body["experts"] == [CID_A]

    page.select_option("#f-algorithm-demonstration-credit", "false")  # off: Alg. 5.1, not sent
    page.fill("#f-observation-walls_embedding", "")
    page.fill("#f-observation-walls_embedding_size", "")
    page.click("#submit-task")
    expect(page.locator("#submit-result")).to_contain_text("created")
    assert "algorithm" not in state.posted_tasks[-1]
    assert state.posted_tasks[-1]["observation"] == {"kind": "odmtl", "window": 3}


def test_the_form_sets_an_expert_rate_schedule(page: Any, mmc: Any) -> None:
    """algorithm.demonstration.rate_end: refused without experts and without a step budget,
    sent with the start rate where it applies."""
    server, state, _ = mmc
    page.goto(f"{server.url}/submit")
    sign_in_as_alice(page)
    small_task(page)
    page.fill("#f-algorithm-demonstration-rate_end", "0")
    before = len(state.posted_tasks)
    page.click("#submit-task")
    expect(page.locator("#err-algorithm-demonstration-rate_end")).to_contain_text(
        "only with experts"
    )
    page.fill("#f-experts", CID_A)
    page.fill("#f-budget-steps", "")
    page.click("#submit-task")
    expect(page.locator("#err-algorithm-demonstration-rate_end")).to_contain_text(
        "needs a step budget"
    )
    assert len(state.posted_tasks) == before
    page.fill("#f-budget-steps", "20000")
    page.fill("#f-algorithm-demonstration-rate", "0.3")
    page.click("#submit-task")
    expect(page.locator("#submit-result")).to_contain_text("created")
    assert state.posted_tasks[-1]["algorithm"] == {"demonstration": {"rate": 0.3, "rate_end": 0}}


def test_the_form_chooses_the_delivered_policy(page: Any, mmc: Any) -> None:
    """selection.keep_best: the final policy by default (no selection sent), the best evaluated
    one on request; the evaluation interval is refused without it."""
    server, state, _ = mmc
    page.goto(f"{server.url}/submit")
    sign_in_as_alice(page)
    small_task(page)
    options = page.locator("#f-selection-keep_best option")
    assert options.evaluate_all("os => os.map(o => o.value)") == ["", "time", "cost"]
    page.fill("#f-selection-eval_every", "2")
    before = len(state.posted_tasks)
    page.click("#submit-task")
    expect(page.locator("#err-selection-eval_every")).to_contain_text("only when delivering")
    assert len(state.posted_tasks) == before
    page.fill("#f-selection-eval_every", "")
    page.click("#submit-task")
    expect(page.locator("#submit-result")).to_contain_text("created")
    assert "selection" not in state.posted_tasks[-1]
    page.select_option("#f-selection-keep_best", "cost")
    page.fill("#f-selection-eval_every", "2")
    page.click("#submit-task")
    expect(page.locator("#submit-result")).to_contain_text("created")
    assert state.posted_tasks[-1]["selection"] == {"keep_best": "cost", "eval_every": 2}
