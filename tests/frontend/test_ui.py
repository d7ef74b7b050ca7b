"""The web UI in headless Chromium against the fake gateway (tests/frontend/fake_api.py):
what the pages show, and what the browser sends."""

from __future__ import annotations

import re
from typing import Any

import httpx
import pytest

from tests.frontend.conftest import LiveServer, screenshot, sign_in_as_alice
from tests.frontend.fake_api import ALICE, CID_A, CID_B, XSS, FakeState

expect = pytest.importorskip("playwright.sync_api", reason="pip install playwright").expect


def model_ids(page: Any) -> list[int]:
    return [
        int(x)
        for x in page.locator("#models-table tbody tr").evaluate_all(
            "rows => rows.map(r => r.dataset.modelId)"
        )
    ]


def wait_for_models(page: Any, ids: list[int]) -> None:
    """Wait until the table lists exactly ``ids`` (filters are debounced, answers asynchronous)."""
    page.wait_for_function(
        "ids => JSON.stringify([...document.querySelectorAll('#models-table tbody tr')]"
        ".map(r => Number(r.dataset.modelId))) === JSON.stringify(ids)",
        arg=ids,
    )


# ------------------------------------------------------------------------- serving


def test_gateway_serves_ui_routes_but_keeps_api_errors_json(server: LiveServer) -> None:
    with httpx.Client(base_url=server.url) as c:
        for path in ("/", "/models", "/tasks/7", "/workers?status=idle"):
            r = c.get(path)
            assert r.status_code == 200 and '<main id="main">' in r.text, path
        assert c.get("/js/app.js").headers["content-type"].startswith("text/javascript")
        assert c.get("/js/nope.js").status_code == 404  # a missing asset is not a route
        r = c.get("/api/nope")
        assert r.status_code == 404 and r.json()["detail"]["rule"] == "not_found"
        assert c.put("/api/models").status_code == 405  # the UI mount does not swallow /api
        assert c.get("/rpc").status_code == 404


# ------------------------------------------------------------------------- models


def test_models_list_renders_and_filters(page: Any, server: LiveServer, state: FakeState) -> None:
    page.goto(f"{server.url}/models")
    expect(page.locator("#models-table tbody tr")).to_have_count(len(state.models))
    assert model_ids(page) == [m["id"] for m in state.models]
    first = page.locator('#models-table tr[data-model-id="1"]')
    expect(first).to_contain_text("3 agents · 10×10")
    expect(first.locator(".reputation")).to_have_text("0.842")
    screenshot(page, "models")

    page.fill('input[name="agents"]', "3")
    wait_for_models(page, [1, 4])
    assert state.queries("/api/models")[-1] == {"agents": "3", "limit": "100"}
    assert page.url.endswith("/models?agents=3")

    page.fill('input[name="walls"]', "2")
    wait_for_models(page, [4])
    page.fill('input[name="walls"]', "")
    page.fill('input[name="min_reputation"]', "0.5")
    wait_for_models(page, [1])
    assert state.queries("/api/models")[-1] == {"agents": "3", "min_reputation": "0.5",
                                                  "limit": "100"}

    page.fill('input[name="q"]', "nothing like this")
    expect(page.locator("#no-models")).to_have_text("No model matches these filters.")
    page.click("text=Clear")
    wait_for_models(page, [m["id"] for m in state.models])

    # A filtered URL restores its filters.
    page.goto(f"{server.url}/models?domain=3")
    expect(page.locator('input[name="domain"]')).to_have_value("3")
    wait_for_models(page, [1, 4])
    assert state.queries("/api/models")[-1] == {"domain": "3", "limit": "100"}


def test_model_descriptions_are_text_not_html(page: Any, server: LiveServer) -> None:
    page.goto(f"{server.url}/models/3")
    expect(page.locator("#model-description")).to_contain_text(XSS)
    assert page.locator("#model-page img").count() == 0
    assert page.evaluate("window.__xss") is None


def test_model_page_shows_card_cid_curve(page: Any, server: LiveServer, state: FakeState) -> None:
    page.goto(f"{server.url}/models")
    page.click('#models-table tr[data-model-id="1"] a')
    expect(page).to_have_url(f"{server.url}/models/1")
    m = state.models[0]
    expect(page.locator("#model-cid")).to_have_text(CID_A)
    expect(page.locator("#owner-reputation")).to_have_text(str(m["owner_reputation"]))
    expect(page.locator("#owner-model-reputation")).to_have_text(
        str(m["owner_model_reputation"]))
    expect(page.locator("#model-description")).to_have_text(m["description"])
    card = page.locator("#model-card")
    expect(card).to_contain_text("ODMTL, window 3")
    expect(card).to_contain_text("92,906 (actor 40,805, critic 52,101)")
    expect(card).to_contain_text("drlaas-model/1")

    links = page.locator("#downloads a")
    assert links.evaluate_all("as => as.map(a => a.getAttribute('href'))") == [
        "/api/models/1/download?file=model.safetensors",
        "/api/models/1/download?file=model.json",
    ]

    success = page.locator('#model-curve [data-chart="Success rate"]')
    train = success.locator('polyline[data-series="training"]')
    assert int(train.get_attribute("data-count")) == len(m["curve"])
    # A rising success rate is drawn rising: SVG y shrinks upwards.
    pts = [tuple(map(float, p.split(","))) for p in train.get_attribute("points").split()]
    assert len(pts) == len(m["curve"])
    assert pts[-1][0] > pts[0][0] and pts[-1][1] < pts[0][1]
    expect(page.locator('#model-curve [data-chart="Cost"] polyline')).to_have_count(1)
    screenshot(page, "model")

    # A deep link works (index.html fallback + client router).
    page.goto(f"{server.url}/models/2")
    expect(page.locator("#model-page")).to_have_attribute("data-model-id", "2")
    expect(page.locator("#model-cid")).to_have_text(state.models[1]["cid"])


def test_missing_model_shows_the_gateways_message(page: Any, server: LiveServer) -> None:
    page.goto(f"{server.url}/models/99")
    expect(page.locator(".error-box")).to_have_text("no model 99 (or not indexed yet)")


# ------------------------------------------------------------------------- task form


def test_task_form_shows_errors_next_to_fields(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    page.goto(f"{server.url}/submit")
    sign_in_as_alice(page)
    page.fill("#f-env-agents", "0")
    page.fill("#f-observation-window", "4")
    page.fill("#f-env-walls_min", "3")
    page.fill("#f-env-walls_max", "1")
    page.fill("#f-payment_eth", "1,5")
    page.fill("#f-num_workers", "17")
    page.fill("#f-budget-steps", "")
    page.fill("#f-budget-minutes", "")
    page.fill("#f-min_rating", "1.5")
    page.click("#submit-task")
    expect(page.locator("#err-env-agents")).to_have_text("must be at least 1")
    expect(page.locator("#err-observation-window")).to_have_text("must be odd")
    expect(page.locator("#err-env-walls_max")).to_have_text("must be at least the minimum")
    expect(page.locator("#err-payment_eth")).to_have_text("enter an amount like 0.01")
    expect(page.locator("#err-num_workers")).to_have_text("must be at most 16")
    expect(page.locator("#err-budget")).to_have_text("give steps and/or minutes")
    expect(page.locator("#err-min_rating")).to_have_text("must be at most 1")
    expect(page.locator("#f-env-agents")).to_have_attribute("aria-invalid", "true")
    expect(page.locator("#err-env-rows")).to_be_hidden()
    assert state.posted_tasks == [] and not [
        r for r in state.requests if r[0] == "POST" and r[1] == "/api/tasks"
    ]
    screenshot(page, "submit-errors")

    # Errors that depend on two fields: agents vs grid, window vs grid, walls vs grid size.
    page.fill("#f-env-agents", "9")
    page.fill("#f-env-rows", "3")
    page.fill("#f-env-cols", "3")
    page.fill("#f-observation-window", "3")
    page.fill("#f-env-walls_min", "0")
    page.click("#submit-task")
    expect(page.locator("#err-env-agents")).to_have_text("9 agents and a target do not fit on 3×3")
    expect(page.locator("#err-observation-window")).to_have_text(
        "must be less than 3 (the smaller grid side)"
    )
    expect(page.locator("#err-env-walls_max")).to_have_text("walls need a grid of at least 4×4")
    expect(page.locator("#err-payment_eth")).to_have_text("enter an amount like 0.01")


def test_submitting_posts_the_right_json(page: Any, server: LiveServer, state: FakeState) -> None:
    page.goto(f"{server.url}/submit")
    sign_in_as_alice(page)
    page.fill("#f-env-agents", "4")
    page.fill("#f-env-rows", "12")
    page.fill("#f-env-cols", "10")
    page.fill("#f-env-walls_min", "1")
    page.fill("#f-env-walls_max", "3")
    page.select_option("#f-env-moves", "8")
    page.fill("#f-env-intensity", "1e8:1e9")
    page.fill("#f-observation-window", "5")
    page.fill("#f-budget-steps", "50000")
    page.fill("#f-budget-minutes", "30")
    page.fill("#f-seed", "7")
    page.fill("#f-domain", "3")
    page.fill("#f-num_workers", "3")
    page.fill("#f-min_reputation", "0.5")
    page.fill("#f-min_rating", "0.25")
    page.fill("#f-min_cpu_cores", "2")
    page.fill("#f-min_ram_gb", "4")
    page.fill("#f-deadline_s", "1800")
    page.fill("#f-payment_eth", "0.123456789012345678")
    page.click("#submit-task")
    expect(page.locator("#submit-result")).to_contain_text("Task #4 created")
    assert state.posted_tasks == [
        {
            "env": {
                "agents": 4,
                "rows": 12,
                "cols": 10,
                "walls": [1, 3],
                "moves": 8,
                "intensity": {"kind": "uniform", "values": [1e8, 1e9]},
            },
            "observation": {"kind": "odmtl", "window": 5},
            "budget": {"steps": 50000, "minutes": 30},
            "domain": 3,
            "num_workers": 3,
            "min_reputation": 0.5,
            "min_rating": 0.25,
            "min_cpu_cores": 2,
            "min_ram_gb": 4,
            "deadline_s": 1800,
            "payment_wei": 123456789012345678,  # exact: past 2**53, sent as an integer literal
            "seed": 7,
        }
    ]
    assert re.search(r'"payment_wei": 123456789012345678\b', state.posted_raw[0])
    assert state.auth_headers == ["Bearer demo-token-alice"]
    page.click("#submit-result a")
    expect(page).to_have_url(f"{server.url}/tasks/4")
    expect(page.locator("#task-status")).to_have_text("open")


def test_non_odmtl_task_sends_no_window(page: Any, server: LiveServer, state: FakeState) -> None:
    page.goto(f"{server.url}/submit")
    sign_in_as_alice(page)
    page.select_option("#f-observation-kind", "cmtl")
    expect(page.locator('[data-field="observation.window"]')).to_be_hidden()
    page.click("#submit-task")
    expect(page.locator("#submit-result")).to_contain_text("created")
    assert state.posted_tasks[0]["observation"] == {"kind": "cmtl"}
    assert state.posted_tasks[0]["payment_wei"] == 10**16


def test_server_validation_errors_land_on_their_field(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    page.goto(f"{server.url}/submit")
    sign_in_as_alice(page)
    page.fill("#f-env-agents", "9")  # the fake gateway allows at most 8
    page.click("#submit-task")
    expect(page.locator("#err-env-agents")).to_have_text("at most 8 agents here")
    expect(page.locator("#f-env-agents")).to_have_attribute("aria-invalid", "true")
    assert state.posted_tasks == []


def test_submit_without_sign_in_says_so(page: Any, server: LiveServer, state: FakeState) -> None:
    page.goto(f"{server.url}/submit")
    page.click("#submit-task")
    expect(page.locator("#form-error")).to_contain_text("Sign in first (top right)")
    expect(page.locator("#form-error")).not_to_contain_text("bearer")  # the API's words
    assert state.auth_headers == [None]


def test_without_demo_users_the_ui_shows_the_curl_sign_in(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    state.demo_users = False
    page.goto(f"{server.url}/models")
    expect(page.locator("#demo-sign-in")).to_have_count(0)
    page.click("#how-sign-in")
    help_text = page.locator("#curl-help").inner_text()
    assert f"curl -s -X POST {server.url}/api/auth/nonce" in help_text
    assert f"{server.url}/api/auth/token" in help_text
    # A pasted token is used as the bearer token.
    page.fill("#token-input", "demo-token-bob")
    page.click("text=Use token")
    expect(page.locator("#me .addr")).to_have_attribute("title", state.tasks[1]["requester"])
    page.click("#sign-out")
    expect(page.locator("#token-input")).to_be_visible()


# ------------------------------------------------------------------------- tasks


def test_tasks_list_updates_status_live(page: Any, server: LiveServer, state: FakeState) -> None:
    page.goto(f"{server.url}/tasks")
    row2 = page.locator('#tasks-table tr[data-task-id="2"]')
    expect(row2).to_have_attribute("data-status", "open")
    expect(page.locator("#tasks-table tbody tr")).to_have_count(3)
    expect(row2).to_contain_text("0.005 ETH")
    screenshot(page, "tasks")
    page.evaluate("window.__sameDocument = true")
    state.task(2)["status"] = "cancelled"
    state.tasks.append({**state.task(3), "id": 9, "status": "open"})
    # The 2 s poll picks both up without a reload.
    expect(row2).to_have_attribute("data-status", "cancelled", timeout=5000)
    expect(row2.locator(".pill")).to_have_text("cancelled")
    expect(page.locator('#tasks-table tr[data-task-id="9"]')).to_be_visible(timeout=5000)
    assert page.evaluate("window.__sameDocument") is True
    assert len(state.queries("/api/tasks")) >= 2

    page.select_option("#task-status-filter", "open")
    expect(page.locator("#tasks-table tbody tr")).to_have_count(2)
    assert state.queries("/api/tasks")[-1] == {"status": "open", "limit": "100"}


def test_only_mine_asks_for_the_signed_in_requester(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    page.goto(f"{server.url}/tasks")
    sign_in_as_alice(page)
    page.check("#task-mine")
    page.wait_for_function("() => document.querySelectorAll('#tasks-table tbody tr').length === 2")
    assert state.queries("/api/tasks")[-1] == {"requester": ALICE, "limit": "100"}
    ids = page.locator("#tasks-table tbody tr").evaluate_all("rs => rs.map(r => r.dataset.taskId)")
    assert ids == ["3", "1"]


def test_polling_stops_when_leaving_the_page(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    page.goto(f"{server.url}/tasks")
    expect(page.locator("#tasks-table")).to_be_visible()
    page.click("#nav >> text=Workers")
    expect(page.locator("#workers-table")).to_be_visible()
    before = len(state.queries("/api/tasks"))
    page.wait_for_timeout(4500)
    assert len(state.queries("/api/tasks")) == before


def test_polling_pauses_while_the_tab_is_hidden(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    page.goto(f"{server.url}/tasks")
    expect(page.locator("#tasks-table")).to_be_visible()
    show = """hidden => {
        Object.defineProperty(document, "hidden", {configurable: true, get: () => hidden});
        Object.defineProperty(document, "visibilityState", {configurable: true,
            get: () => hidden ? "hidden" : "visible"});
        document.dispatchEvent(new Event("visibilitychange"));
    }"""
    page.evaluate(show, True)
    page.wait_for_timeout(500)  # a request already under way may still land
    before = len(state.queries("/api/tasks"))
    page.wait_for_timeout(4500)  # two poll periods
    assert len(state.queries("/api/tasks")) == before
    page.evaluate(show, False)  # shown again: polled at once, not a period later
    page.wait_for_timeout(800)
    resumed = len(state.queries("/api/tasks"))
    assert resumed > before
    page.wait_for_timeout(2500)
    assert len(state.queries("/api/tasks")) > resumed  # and polling goes on


def test_task_page_shows_timeline_offers_outcomes_and_live_curve(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    page.goto(f"{server.url}/tasks/1")
    t = state.task(1)
    expect(page.locator("#timeline li")).to_have_count(len(t["timeline"]))
    expect(page.locator("#timeline li").first).to_contain_text("TaskAdded")
    # an event the index kept without its rows says so, and why
    expect(page.locator("#timeline li .error")).to_have_count(1)
    expect(page.locator("#timeline li .error")).to_contain_text("not indexed: DataError")
    expect(page.locator("#task-offers tbody tr")).to_have_count(2)
    expect(page.locator("#task-offers")).to_contain_text("accepted")
    expect(page.locator("#task-outcomes")).to_contain_text("No outcome submitted yet")
    expect(page.locator("#task-spec-cid")).to_have_text(t["description"])
    curve = page.locator('#task-curve [data-chart="Success rate"] polyline')
    expect(curve).to_have_attribute("data-count", "3")
    guided = page.locator('#task-curve [data-chart="Expert-guided episodes"] polyline')
    expect(guided).to_have_count(0)  # no expert-guided episodes: no such panel
    screenshot(page, "task")

    # The worker posts progress and an outcome; the page follows within a poll or two.
    # (an MEDC job's points carry guided_share, kept by the gateway as an extra metric)
    w = t["offers"][0]["worker"]
    t["progress"] += [
        {"worker": w, "step": 8192, "success": 0.5, "time": 50, "cost": 70,
         "extra": {"guided_share": 0.12}},
        {"worker": w, "step": 10240, "success": 0.6, "time": 45, "cost": 64,
         "extra": {"guided_share": 0.08}},
    ]
    expect(curve).to_have_attribute("data-count", "5", timeout=5000)
    expect(guided).to_have_attribute("data-count", "2")
    expect(page.locator("#progress-summary")).to_contain_text("latest step 10,240, success 0.6")
    t["outcomes"].append(
        {"worker": t["offers"][0]["worker"], "cid": CID_A, "review": None, "accepted": None}
    )
    t["status"] = "completed"
    expect(page.locator("#task-status")).to_have_text("completed", timeout=5000)
    expect(page.locator("#outcomes-table tbody tr")).to_have_count(1)
    # CID_A is listed as model 1 (looked up by its CID): a link to its page
    expect(page.locator("#outcomes-table a")).to_have_attribute("href", "/models/1")
    # an outcome the requester left unreviewed and the close paid: no review of 0/5 shown
    t["outcomes"].append(
        {"worker": t["offers"][1]["worker"], "cid": CID_B, "review": None, "accepted": True}
    )
    paid = page.locator(f'#outcomes-table tr[data-worker="{t["offers"][1]["worker"]}"]')
    expect(paid).to_contain_text("not reviewed: paid at close", timeout=5000)
    expect(paid.locator("button")).to_have_count(0)
    expect(page.locator("#task-summary")).to_contain_text("the final policy")
    expect(page.locator("#task-selection")).to_have_count(0)
    # a task whose spec keeps the best evaluated policy says so (spec selection.keep_best)
    page.goto(f"{server.url}/tasks/3")
    expect(page.locator("#task-selection")).to_have_text(
        "the best evaluated policy by moving cost (evaluated every 4 updates)"
    )


# ------------------------------------------------------------------------- workers


def test_leaderboard_is_sorted_by_reputation(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    page.goto(f"{server.url}/workers")
    rows = page.locator("#workers-table tbody tr")
    expect(rows).to_have_count(len(state.workers))
    shown = rows.evaluate_all("rs => rs.map(r => r.dataset.address)")
    expected = [w["address"] for w in sorted(state.workers, key=lambda w: -w["reputation"])]
    assert shown == expected
    assert shown != [w["address"] for w in state.workers]  # the fake answers unsorted
    reps = [float(x) for x in page.locator("#workers-table .reputation").all_inner_texts()]
    assert reps == sorted(reps, reverse=True)
    assert page.locator("#workers-table .rank").all_inner_texts() == ["1", "2", "3", "4"]
    top = rows.first
    expect(top).to_contain_text("16 CPU · 64 GB RAM · GPU 2")
    expect(top).to_contain_text("20 / 19 / 19")
    assert state.queries("/api/workers")[-1].get("sort") == "reputation"
    screenshot(page, "workers")

    page.select_option('select[name="status"]', "idle")
    expect(rows).to_have_count(1)
    assert state.queries("/api/workers")[-1] == {"status": "idle", "sort": "reputation",
                                               "limit": "100"}


def test_navigation_is_client_side(page: Any, server: LiveServer) -> None:
    page.goto(f"{server.url}/")
    expect(page.locator("#nav a.active")).to_have_text("Models")
    page.evaluate("window.__sameDocument = true")
    for name, heading in (
        ("Tasks", "Tasks"),
        ("Workers", "Workers leaderboard"),
        ("Submit a task", "Submit a training task"),
        ("Models", "Models"),
    ):
        page.click(f"#nav >> text={name}")
        expect(page.locator("main h1")).to_have_text(heading)
        expect(page.locator("#nav a.active")).to_have_text(name)
    page.go_back()
    expect(page.locator("main h1")).to_have_text("Submit a training task")
    assert page.evaluate("window.__sameDocument") is True
    page.goto(f"{server.url}/no/such/page")
    expect(page.locator("main h1")).to_have_text("Not found")


def test_lists_page_through_more_rows_than_one_answer(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    """The API answers at most 100 rows: the list said "N models" and showed the first 100
    with no way to the rest (audit of 2026-12-03, F10)."""
    base = state.models[0]
    state.models[:] = [{**base, "id": i, "cid": f"{base['cid'][:-4]}{i:04d}"}
                       for i in range(1, 231)]
    page.goto(f"{server.url}/models")
    wait_for_models(page, list(range(1, 101)))
    expect(page.locator("#models-count")).to_have_text("230 models")
    expect(page.locator("#models-pager .range")).to_have_text("1–100 of 230")
    expect(page.locator("#models-pager .prev")).to_be_disabled()
    page.click("#models-pager .next")
    wait_for_models(page, list(range(101, 201)))
    assert page.url.endswith("/models?offset=100")
    assert state.queries("/api/models")[-1] == {"limit": "100", "offset": "100"}
    page.click("#models-pager .next")
    wait_for_models(page, list(range(201, 231)))
    expect(page.locator("#models-pager .range")).to_have_text("201–230 of 230")
    expect(page.locator("#models-pager .next")).to_be_disabled()
    # a shared link opens on its page; a new filter starts again at the first
    page.goto(f"{server.url}/models?offset=200")
    wait_for_models(page, list(range(201, 231)))
    page.fill('input[name="walls"]', "2")
    page.wait_for_function(  # the URL changes before the request: wait for its answer too
        "() => !location.search.includes('offset')"
        " && !document.querySelector('#models-results').hasAttribute('aria-busy')"
    )
    assert "offset" not in state.queries("/api/models")[-1]


def test_a_right_to_left_description_reads_right_to_left_in_its_own_block(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    """A description is the model owner's text, in any script: it gets its own direction from
    its first strong character (``dir="auto"``), and an override inside it ends with its
    block. Before, an Arabic description was laid out left to right like the page."""
    state.models[0]["description"] = "نموذج للبحث عن المصدر \u202e gnihtemos"
    page.goto(f"{server.url}/models/1")
    desc = page.locator("#model-description")
    expect(desc).to_contain_text("نموذج")
    assert desc.evaluate("e => e.matches(':dir(rtl)')")
    assert page.locator("#model-cid").evaluate("e => e.matches(':dir(ltr)')")
