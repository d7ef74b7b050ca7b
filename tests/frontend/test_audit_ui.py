"""Findings of a new-user audit of the web UI, in headless Chromium against the fake gateway:
cancelling a task asks first, the task's timeline reads on a phone (ETH, UTC dates), an outcome
links only to a model that is listed, labels are plain words, the leaderboard is live."""

from __future__ import annotations

import re
from typing import Any

import pytest

from tests.frontend.conftest import LiveServer, sign_in_as_alice
from tests.frontend.fake_api import ALICE, CID_A, CID_B, CID_SPEC, W2, FakeState, event, worker

expect = pytest.importorskip("playwright.sync_api", reason="pip install playwright").expect

#: An outcome's CID no listed model has (its worker did not share it).
CID_UNSHARED = "bafkreia3z6n3a6y2b4xq7mhdo5ks2lqgfpv3wuhbwcmn7xyzrt2mh6onyq"


def posts(state: FakeState, path: str) -> list[dict[str, str]]:
    return [q for m, p, q in state.requests if m == "POST" and p == path]


# ------------------------------------------------------------------------ 1. cancel


def test_cancelling_a_task_asks_first(page: Any, server: LiveServer, state: FakeState) -> None:
    page.goto(f"{server.url}/tasks/1")
    sign_in_as_alice(page)
    assert state.task(1)["requester"] == ALICE
    button = page.locator("#cancel-task")
    expect(button).to_be_visible()

    asked: list[str] = []

    def answer(accept: bool) -> Any:
        def handle(dialog: Any) -> None:
            asked.append(dialog.message)
            assert dialog.type == "confirm"
            dialog.accept() if accept else dialog.dismiss()

        return handle

    page.once("dialog", answer(False))
    button.click()
    page.wait_for_timeout(500)
    assert len(asked) == 1 and "Cancel task #1?" in asked[0]
    assert "cannot be undone" in asked[0]
    assert posts(state, "/api/tasks/1/cancel") == []  # dismissed: nothing sent
    expect(page.locator("#task-status")).to_have_text("open")
    expect(page.locator("#task-message")).to_have_text("")

    page.once("dialog", answer(True))
    button.click()
    expect(page.locator("#task-message")).to_contain_text("Cancel: sent")
    assert len(asked) == 2
    assert len(posts(state, "/api/tasks/1/cancel")) == 1
    expect(page.locator("#task-status")).to_have_text("cancelled")
    expect(page.locator("#cancel-task")).to_have_count(0)


# ---------------------------------------------------------------------- 2. timeline


def no_horizontal_overflow(page: Any) -> None:
    """Nothing on the page is wider than the viewport, and no timeline entry is cut."""
    width = page.evaluate("document.documentElement.clientWidth")
    assert page.evaluate("document.documentElement.scrollWidth") <= width
    wide = page.evaluate(
        """() => [...document.querySelectorAll('#timeline li, #timeline li *')]
             .filter(el => el.getBoundingClientRect().right > document.documentElement.clientWidth
                           || el.scrollWidth > el.clientWidth + 1 && el.clientWidth > 0)
             .map(el => el.outerHTML.slice(0, 120))"""
    )
    assert wide == []
    # the training curves shrink to the phone (they do not scroll in their panel)
    assert page.evaluate(
        "(() => { const b = document.querySelector('#task-curve .section-body');"
        " return b.scrollWidth <= b.clientWidth; })()"
    )


def test_the_timeline_reads_on_a_phone_in_eth_and_utc_dates(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    t = state.task(1)
    # the chain's TaskAdded args as the index stores them (ints past 2^53 as strings)
    t["timeline"][0] = event("TaskAdded", 12, {
        "taskId": 1, "requester": ALICE, "domain": 3, "numWorkers": 2,
        "reward": str(10**16), "deadline": 1_746_356_400, "minReputation": 250_000,
        "minRating": 0, "minCpuCores": 1, "minRamGb": 1, "description": CID_SPEC,
    })  # fmt: skip
    t["timeline"].append(event("OutcomeSubmitted", 16, {"taskId": 1, "worker": W2, "cid": CID_B}))
    t["timeline"].append(
        event("PaymentCredited", 17, {"account": W2, "taskId": 1, "amount": 5 * 10**15})
    )
    page.set_viewport_size({"width": 360, "height": 800})
    page.goto(f"{server.url}/tasks/1")
    items = page.locator("#timeline li")
    expect(items).to_have_count(len(t["timeline"]))
    added, offered = items.nth(0), items.nth(1)
    expect(added).to_contain_text("reward: 0.01 ETH")
    expect(added).to_contain_text("deadline: 2025-05-04 11:00:00 UTC")
    expect(added).to_contain_text("min reputation: 0.25")
    expect(added.locator('[data-arg="reward"] [title]')).to_have_attribute("title", f"{10**16} wei")
    expect(added.locator(".when")).to_have_text("2025-05-04 10:00:36 UTC")  # the block's time
    expect(offered).to_contain_text("expiry: 2025-05-04 10:05:00 UTC")
    expect(offered).to_contain_text("match score: 0.91")
    expect(items.last).to_contain_text("amount: 0.005 ETH")
    text = page.locator("#timeline").inner_text()
    for raw in (str(10**16), str(5 * 10**15), "1746356400", "1746353100", "910000"):
        assert raw not in text
    # the task's other times say UTC too (one clock on the page)
    expect(page.locator("#task-summary")).to_contain_text("2025-05-04 11:00:00 UTC")
    no_horizontal_overflow(page)


# ---------------------------------------------------------------------- 3. outcomes


def test_an_outcome_links_only_to_a_listed_model(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    t = state.task(3)
    assert t["outcomes"][0]["cid"] == CID_A and state.models[0]["cid"] == CID_A
    t["outcomes"].append({"worker": W2, "cid": CID_UNSHARED, "review": 4, "accepted": True})
    page.goto(f"{server.url}/tasks/3")
    rows = page.locator("#outcomes-table tbody tr")
    expect(rows).to_have_count(2)
    # listed (the model whose CID it is): a link to that model's page
    expect(rows.nth(0).locator("a")).to_have_attribute("href", "/models/1")
    # not listed: the CID as text to copy, no link to a search that finds nothing
    unshared = rows.nth(1)
    expect(unshared.locator("a")).to_have_count(0)
    expect(unshared.locator("code")).to_have_text(CID_UNSHARED)
    expect(unshared.get_by_role("button", name="Copy")).to_be_visible()
    expect(unshared).to_contain_text("Not listed as a shared model")
    expect(rows.nth(0)).not_to_contain_text("Not listed")
    # the task's own answer says which outcome is listed (model_id): no models search
    assert state.queries("/api/models") == []


# ------------------------------------------------------------------------ 4. labels

JARGON = re.compile(r"\b(?:Eq|Alg|Ch)\.\s*\d|\bR_[A-Z]\b|\b(?:MMC|MEDC|CAE)\b")


def visible_words(page: Any) -> str:
    """What a user reads: the page's text and the choices of its selects (not tooltips)."""
    return page.evaluate(
        """() => document.querySelector('main').innerText + '\\n'
             + [...document.querySelectorAll('main option')].map(o => o.textContent).join('\\n')"""
    )


def test_labels_speak_plain_words(page: Any, server: LiveServer, state: FakeState) -> None:
    state.task(1)["experts"] = [
        {"cid": CID_B, "qos": 0.625, "model_id": 2, "reputation": 0.5, "alloc_id": 9,
         "review": None},
    ]  # fmt: skip
    for path, ready in (
        ("/models/1", "#model-experts li"),
        ("/tasks/1", "#experts-table tbody tr"),
        ("/submit", "#task-form"),
        ("/workers", "#workers-table"),
        ("/models", "#models-table"),
        ("/tasks", "#tasks-table"),
    ):
        page.goto(server.url + path)
        expect(page.locator(ready).first).to_be_visible()
        if path == "/models/1":
            expect(page.locator("#model-experts .usage").first).to_contain_text("probability")
        found = JARGON.findall(visible_words(page))
        assert found == [], f"{path}: {found}"
        if path == "/models/1":  # the references stay, for experts, in the tooltips
            expect(page.locator('#model-chain [title*="Eq. 19"]')).to_have_count(2)
            expect(page.locator("#model-chain dt").nth(1)).to_have_text(
                "Owner's reputation as a sharer"
            )
        if path == "/submit":
            expect(page.locator('label[for="f-algorithm-demonstration-rate"]')).to_have_attribute(
                "title", re.compile("R_E")
            )


# ----------------------------------------------------------------------- 5. workers


def test_the_leaderboard_is_live_and_keeps_the_users_place(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    state.workers[:] = [
        worker(f"0x{i:040x}", "active", round(0.3 + 0.004 * (i % 100), 3), 0.5, 4, 8, 0, [3],
               (i, i, i), i)
        for i in range(1, 151)
    ]  # fmt: skip
    page.set_viewport_size({"width": 1280, "height": 500})
    page.goto(f"{server.url}/workers")
    rows = page.locator("#workers-table tbody tr")
    expect(rows).to_have_count(100)
    page.click("#workers-pager .next")
    expect(page.locator("#workers-pager .range")).to_have_text("101–150 of 150")
    expect(rows).to_have_count(50)
    expect(page.locator("#workers-updated")).to_contain_text("live")
    page.evaluate("window.scrollTo(0, 700)")
    bottom = rows.nth(49)
    page.evaluate(
        "() => { window.__kept = document.querySelector('#workers-table tbody tr:last-child');"
        " window.__pager = document.querySelector('#workers-pager .prev'); }"
    )
    # a half-typed filter is not applied by the polls (applied on change, as before)
    page.evaluate("document.querySelector('input[name=domain]').value = '7'")
    before = len(state.queries("/api/workers"))

    # the chain moves on: a worker on this page climbs to its top, another goes idle
    climber = state.workers[120]
    climber["reputation"] = 0.999
    state.workers[130]["status"] = "idle"
    expect(rows.first).to_have_attribute("data-address", climber["address"], timeout=6000)
    expect(page.locator(f'tr[data-address="{state.workers[130]["address"]}"] .pill')).to_have_text(
        "idle"
    )
    assert len(state.queries("/api/workers")) > before
    assert state.queries("/api/workers")[-1] == {"sort": "reputation", "limit": "100",
                                               "offset": "100"}  # fmt: skip
    # the user's place: the page, the scroll, the rows and pager that did not change
    assert page.url.endswith("/workers?offset=100")
    expect(page.locator("#workers-pager .range")).to_have_text("101–150 of 150")
    assert page.evaluate("window.scrollY") == 700
    assert page.evaluate("window.__kept.isConnected && window.__pager.isConnected") is True
    expect(bottom).to_have_attribute("data-address", page.evaluate("window.__kept.dataset.address"))
    assert page.locator('input[name="domain"]').input_value() == "7"

    # leaving the page stops the polling
    page.click("#nav >> text=Tasks")
    expect(page.locator("#tasks-table")).to_be_visible()
    left = len(state.queries("/api/workers"))
    page.wait_for_timeout(4500)
    assert len(state.queries("/api/workers")) == left


@pytest.mark.parametrize("path", ["/models", "/models/1", "/tasks", "/tasks/1", "/workers"])
def test_no_page_scrolls_sideways_on_a_phone(
    page: Any, server: LiveServer, path: str
) -> None:
    """A table wider than a phone scrolls in its own box; the page itself never scrolls
    sideways (the workers and models lists did: the whole page moved under the thumb)."""
    page.set_viewport_size({"width": 360, "height": 800})
    page.goto(f"{server.url}{path}")
    expect(page.locator("table.list").first).to_be_visible()
    width = page.evaluate("document.documentElement.clientWidth")
    assert page.evaluate("document.documentElement.scrollWidth") <= width, path
