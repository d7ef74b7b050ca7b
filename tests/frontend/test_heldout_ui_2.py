"""Held-out pass on the web UI (fourth, 2026-12-05), in headless Chromium against the fake
gateway: a curve of 10^6 points, ids that name nothing, a gateway answering 5xx or never,
and the way back from each (a Not found view, a Retry). Each test fails on the code before its
fix (its docstring says what happened then)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from tests.frontend.conftest import LiveServer
from tests.frontend.fake_api import FakeState

expect = pytest.importorskip("playwright.sync_api", reason="pip install playwright").expect

OVERLOADED = json.dumps(
    {"detail": {"rule": "overloaded", "msg": "the gateway is busy, retry later"}}
)


def test_a_curve_of_a_million_points_is_drawn_thinned(page: Any, server: LiveServer) -> None:
    """A card's or a worker's curve may hold 10^6 points: the chart took the axes' extent with
    Math.min(...xs), which throws "RangeError: Maximum call stack size exceeded" past ~10^5
    arguments, so no chart was drawn (and a polyline of 10^6 points would freeze the page).
    A lone spike must survive the thinning."""
    page.goto(f"{server.url}/workers")
    expect(page.locator("#workers-table")).to_be_visible()
    got = page.evaluate("""async () => {
      const { lineChart } = await import('/js/chart.js');
      const n = 1000000;
      const pts = Array.from({ length: n }, (_, i) => [i, i === 654321 ? 50 : (i % 7) / 7]);
      const fig = lineChart({ title: 'big', series: [{ label: 'training', points: pts }] });
      const line = fig.querySelector('polyline');
      const drawn = line.getAttribute('points').split(' ').map((p) => p.split(',').map(Number));
      return { count: line.getAttribute('data-count'), drawn: drawn.length,
               top: Math.min(...drawn.map((p) => p[1])),
               ticks: [...fig.querySelectorAll('text.tick')].map((t) => t.textContent) };
    }""")
    assert got["count"] == "1000000"
    assert 0 < got["drawn"] <= 2000, got["drawn"]
    assert got["top"] == 14.0, got  # the spike (y=50) is drawn at the plot's top edge
    assert got["ticks"] == ["0", "20", "40", "0", "200k", "400k", "600k", "800k"], got["ticks"]


@pytest.mark.parametrize(
    ("path", "back"),
    [
        ("/models/999", "Browse models"),
        ("/tasks/999", "Browse tasks"),
        ("/models/abc", "Browse models"),
        ("/tasks/-1", "Browse models"),
        ("/models/%E0", "Browse models"),
    ],
)
def test_an_id_that_names_nothing_is_a_not_found_view(
    page: Any, server: LiveServer, state: FakeState, path: str, back: str
) -> None:
    """/models/999 and /tasks/999 showed only the gateway's message on an empty page, with no
    heading and no way on; /models/abc showed pydantic's "path.mid: Input should be a valid
    integer, ..." and /models/%E0 "URI malformed". Now each is a Not found view with a link."""
    page.goto(server.url + path)
    expect(page.locator("main h1")).to_have_text("Not found")
    expect(page.get_by_role("link", name=back)).to_be_visible()
    if path.endswith("999"):
        expect(page.locator(".error-box")).to_contain_text("no ")  # the gateway's words
    else:
        asked = [p for _, p, _ in state.requests if p.startswith(("/api/models/", "/api/tasks/"))]
        assert not asked, asked  # no id to ask the gateway about


@pytest.mark.parametrize(
    ("path", "api_path", "loaded"),
    [
        ("/models/1", "**/api/models/1", "#model-page"),
        ("/tasks/1", "**/api/tasks/1", "#task-page"),
        ("/models", "**/api/models?*", "#models-table"),
    ],
)
def test_a_page_whose_first_read_failed_offers_a_retry(
    page: Any, server: LiveServer, path: str, api_path: str, loaded: str
) -> None:
    """A 5xx on a model's or a task's first read left the message and nothing to do but
    reload (the task page stopped polling); the models list waited for a filter change."""
    failed = []

    def once(route: Any) -> None:
        if failed:
            route.continue_()
        else:
            failed.append(route.request.url)
            route.fulfill(status=503, content_type="application/json", body=OVERLOADED)

    page.route(api_path, once)
    page.goto(server.url + path)
    expect(page.locator(".error-box")).to_have_text("the gateway is busy, retry later")
    expect(page.locator(loaded)).to_have_count(0)
    retry = page.get_by_role("button", name="Retry")
    retry.focus()
    page.keyboard.press("Enter")  # a real button: reachable and usable from the keyboard
    expect(page.locator(loaded)).to_be_visible()
    expect(page.locator(".error-box")).to_have_count(0)


def test_a_gateway_that_never_answers_is_an_error_not_a_blank_page(
    page: Any, server: LiveServer
) -> None:
    """fetch has no timeout of its own: a gateway that took the connection and never answered
    left the model page empty for ever (and a polling page stopped polling). The page's clock
    is Playwright's, moved past the 30 s the UI waits: no real waiting."""
    page.clock.install()
    hung: list[Any] = []
    page.route(
        "**/api/models/1", lambda route: hung.append(route) if not hung else route.continue_()
    )
    with page.expect_request("**/api/models/1"):
        page.goto(f"{server.url}/models/1")
    expect(page.locator("#model-page")).to_have_count(0)
    page.clock.fast_forward("00:31")
    expect(page.locator(".error-box")).to_contain_text("did not answer within 30 s")
    page.get_by_role("button", name="Retry").click()
    expect(page.locator("#model-page")).to_be_visible()


COUNT_TASK_READS = """
window.__taskReads = 0;
const fetch0 = window.fetch.bind(window);
window.fetch = (url, opts) => {
  if (/\\/api\\/tasks\\/1$/.test(String(url))) window.__taskReads += 1;
  return fetch0(url, opts);
};
"""


@pytest.mark.parametrize("status", ["open", "closed", "cancelled"])
def test_a_final_task_is_polled_every_30_s_not_every_2(
    page: Any, server: LiveServer, state: FakeState, status: str
) -> None:
    """The task page read the whole task (up to 10,000 curve points) every 2 s for as long as it
    stayed open, a closed or cancelled task too. The page's clock is Playwright's and the reads
    are counted in the page (its fetch), so the count is exact."""
    state.task(1)["status"] = status
    page.add_init_script(COUNT_TASK_READS)
    page.clock.install()
    page.goto(f"{server.url}/tasks/1")
    expect(page.locator("#task-status")).to_have_text(status)
    expect(page.locator("#task-updated")).to_contain_text("updated")
    assert page.evaluate("window.__taskReads") == 1
    page.clock.fast_forward(2500)
    reads = page.evaluate("window.__taskReads")
    if status == "open":
        assert reads == 2  # live: the next read is due after 2 s
        return
    assert reads == 1, reads
    expect(page.locator("#task-updated")).to_contain_text(f"{status} · updated")
    page.clock.fast_forward(30000)
    assert page.evaluate("window.__taskReads") == 2  # still read, slowly


def test_a_baseline_named_like_an_object_member_is_shown_by_its_name(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    """A card's baseline name is any ``[a-z][a-z0-9_-]{0,31}`` (the gateway's parser): one named
    "constructor" found Object's own member in the page's label table and its row read
    "function Object() { [native code] }"."""
    from backend.schemas.cards import BaselineFiguresPublic

    BaselineFiguresPublic(name="constructor", success=0.5)  # the gateway lets it through
    m = next(x for x in state.models if x.get("heldout"))
    m["heldout"]["readings"][0]["baselines"][0]["name"] = "constructor"
    page.goto(f"{server.url}/models/{m['id']}")
    row = page.locator('#heldout-table tr[data-policy="constructor"] td').first
    expect(row).to_have_text("constructor")


@pytest.mark.parametrize(
    ("path", "api_path", "loaded"),
    [
        ("/models/1", "**/api/models/1", "#model-page"),
        ("/models", "**/api/models?*", "#models-table"),
    ],
)
def test_a_page_waiting_for_the_gateway_says_it_is_loading(
    page: Any, server: LiveServer, path: str, api_path: str, loaded: str
) -> None:
    """Until its first answer a model page was blank (a list page showed its filters over
    nothing), for up to the 30 s a read may take: it now says "Loading…" until then."""
    held: list[Any] = []
    page.route(api_path, lambda route: held.append(route) if not held else route.continue_())
    with page.expect_request(api_path):
        page.goto(server.url + path)
    expect(page.get_by_role("status")).to_have_text("Loading…")
    held[0].continue_()
    expect(page.locator(loaded)).to_be_visible()
    expect(page.locator("#page-loading")).to_have_count(0)


def test_a_deadline_reads_the_same_in_the_list_and_on_the_task_page(
    browser: Any, server: LiveServer, state: FakeState
) -> None:
    """The task page gives the chain's times in UTC, marked so; the task list gave the same
    deadline in the reader's zone with no zone at all: in Tokyo a task "due 11:00 UTC" read
    "20:00" in the list, and nothing said which was right."""
    state.task(1)["deadline"] = 1_746_356_400  # 2025-05-04 11:00:00 UTC
    ctx = browser.new_context(timezone_id="Asia/Tokyo", viewport={"width": 1280, "height": 900})
    try:
        page = ctx.new_page()
        page.goto(f"{server.url}/tasks")
        expect(page.locator('#tasks-table tr[data-task-id="1"] td').last).to_have_text(
            "2025-05-04 11:00:00 UTC"
        )
        page.goto(f"{server.url}/tasks/1")
        expect(page.locator("#task-summary")).to_contain_text("2025-05-04 11:00:00 UTC")
    finally:
        ctx.close()


@pytest.mark.parametrize("bad", ["abc", "48", "-1"])
def test_a_domain_that_is_none_is_said_at_the_field_not_polled(
    page: Any, server: LiveServer, state: FakeState, bad: str
) -> None:
    """The leaderboard sent its domain filter as typed: a link with ?domain=abc (or 48, past the
    UMC's 48 domains) was answered 422 by the gateway, asked again on every 2 s poll, and the
    list showed only "update failed". The field now says what a domain is and the list stays."""
    page.goto(f"{server.url}/workers?domain={bad}")
    expect(page.locator("#workers-table")).to_be_visible()
    expect(page.locator("#workers-domain-error")).to_contain_text("whole number 0-47")
    expect(page.locator('input[name="domain"]')).to_have_attribute("aria-invalid", "true")
    assert all("domain" not in q for q in state.queries("/api/workers")), state.queries(
        "/api/workers"
    )
    page.fill('input[name="domain"]', "1")
    page.press('input[name="domain"]', "Enter")
    expect(page.locator("#workers-domain-error")).to_be_hidden()
    expect(page.locator('input[name="domain"]')).not_to_have_attribute("aria-invalid", "true")
    expect(page).to_have_url(f"{server.url}/workers?domain=1")
