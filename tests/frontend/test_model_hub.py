"""The model page as a model hub shows it, and the task list's environments, in headless
Chromium against the fake gateway, whose model details are built by the real card parser
(backend/schemas/cards.py) and validated by the real response model."""

from __future__ import annotations

from typing import Any

import pytest

from tests.frontend.conftest import LiveServer, screenshot
from tests.frontend.fake_api import BOB, CID_B, FakeState

expect = pytest.importorskip("playwright.sync_api", reason="pip install playwright").expect


def ci(value: float, interval: list[float]) -> str:
    return f"{value:.2f} [{interval[0]:.2f}, {interval[1]:.2f}]"


def test_model_page_shows_heldout_curve_provenance_and_human_units(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    m = state.models[0]
    m["description"] = '<img src=x onerror="window.__xss=1"> zoo model'
    m["experts"][1]["ref"] = "<b>runs/local</b>"
    page.goto(f"{server.url}/models/1")
    expect(page.locator("#model-title")).to_have_text("odmtl-3a")
    expect(page.locator("#model-description")).to_have_text(m["description"])

    # held-out table: per reading model the model, the baselines and the oracle, the card's
    # numbers, each time against the oracle's
    for f in m["heldout"]["readings"]:
        group = page.locator(f'#heldout-table tbody[data-reading-model="{f["reading_model"]}"]')
        policies = ["model", *(b["name"] for b in f["baselines"]), "oracle"]
        assert (
            group.locator("tr[data-policy]").evaluate_all("rs => rs.map(r => r.dataset.policy)")
            == policies
            == ["model", "bayes", "uniform", "random", "oracle"]
        )
        for policy, figures in (("model", f), *((b["name"], b) for b in f["baselines"])):
            row = group.locator(f'tr[data-policy="{policy}"]')
            expect(row.locator(".success")).to_have_text(f"{100 * figures['success']:.1f}%")
            expect(row.locator(".time")).to_have_text(ci(figures["time"], figures["time_ci"]))
            expect(row.locator(".cost")).to_have_text(ci(figures["cost"], figures["cost_ci"]))
            ratio = figures["time"] / f["oracle_time"]
            expect(row.locator(".ratio")).to_have_text(f"{ratio:.2f}×")
        oracle = group.locator('tr[data-policy="oracle"]')
        expect(oracle.locator(".time")).to_have_text(f"{f['oracle_time']:.2f}")
        expect(oracle.locator(".success")).to_have_text("—")  # the card does not say

    # the curve: time and cost against env steps, every point of the card, falling
    for chart in ("Search time", "Cost"):
        line = page.locator(f'#model-curve [data-chart="{chart}"] polyline')
        expect(line).to_have_count(1)
        assert int(line.get_attribute("data-count")) == len(m["curve"])
        pts = [tuple(map(float, p.split(","))) for p in line.get_attribute("points").split()]
        assert pts[-1][0] > pts[0][0] and pts[-1][1] > pts[0][1]  # SVG y grows downwards

    # provenance: the producing task and the expert models are links; a local expert is text
    expect(page.locator("#produced-by a")).to_have_attribute("href", "/tasks/3")
    experts = page.locator("#model-experts li")
    expect(experts).to_have_count(2)
    expect(experts.nth(0).locator("a")).to_have_attribute("href", "/models/2")
    expect(experts.nth(0).locator(".cid")).to_have_attribute("title", CID_B)
    expect(experts.nth(1)).to_contain_text("<b>runs/local</b>")
    # what the run did with each expert, from the card (a record that does not validate: none)
    expect(experts.nth(0).locator(".usage")).to_have_text(
        " · guided 630 episodes, its action taken in 82.5% of 5,000 decisions (its first choice "
        "in 62%), picked with probability 0.5"
    )
    expect(experts.nth(1).locator(".usage")).to_have_count(0)
    # the worker's trial of the expert on the task after the run, with the review it suggests
    expect(experts.nth(0).locator(".trial")).to_contain_text("time 13.7 steps (1.43× the oracle)")
    expect(experts.nth(0).locator(".suggested-review")).to_have_text("suggested review 3/5")
    expect(experts.nth(1).locator(".trial")).to_have_count(0)
    # the card's training.selected: the delivered policy is the best evaluated, not the last
    expect(page.locator("#model-selected")).to_contain_text("best evaluated policy by episode time")

    # chain values in human units: QoS a fraction, the price in ETH (wei on hover)
    req = page.locator('#model-requests tr[data-alloc-id="5"]')
    expect(req.locator(".qos")).to_have_text("0.731")
    expect(req.locator(".price")).to_have_text("0.000001234567890123 ETH")
    expect(req.locator(".price")).to_have_attribute("title", "1234567890123 wei")
    expect(req.locator(".addr")).to_have_attribute("title", BOB)
    expect(page.locator("#model-reputation")).to_have_text(str(m["reputation"]))
    assert page.locator("#model-page img, #model-page b").count() == 0
    assert page.evaluate("window.__xss") is None
    screenshot(page, "model-hub")

    page.click("#produced-by a")  # client-side navigation to the task
    expect(page.locator("#task-page")).to_have_attribute("data-task-id", "3")


def test_model_without_heldout_shows_its_final_evaluation(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    m = state.models[1]
    page.goto(f"{server.url}/models/2")
    expect(page.locator("#final-eval")).to_contain_text(f"{100 * m['final_eval']['success']:.1f}%")
    expect(page.locator("#heldout-table")).to_have_count(0)
    expect(page.locator("#produced-by")).to_contain_text("uploaded by its owner")
    expect(page.locator("#model-experts")).to_contain_text("trained from scratch")
    expect(page.locator("#model-selected")).to_have_count(0)  # its last policy


@pytest.mark.parametrize(
    ("state_name", "note"),
    [("pending", "not read from the content store yet"), ("missing", "could not find it"),
     ("invalid", "not a task spec")],
)
def test_a_task_without_its_spec_says_why(
    page: Any, server: LiveServer, state: FakeState, state_name: str, note: str
) -> None:
    """The task page of a task whose spec the index has not got says why (spec_state), next to
    the CID; a task with its spec shows no such note."""
    state.task(1).update(spec=None, env=None, spec_state=state_name)
    page.goto(f"{server.url}/tasks/1")
    expect(page.locator("#task-spec-state")).to_contain_text(note)
    page.goto(f"{server.url}/tasks/2")
    expect(page.locator("#task-spec-cid")).to_be_visible()
    expect(page.locator("#task-spec-state")).to_have_count(0)


def test_task_list_shows_each_tasks_environment(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    state.task(1)["env"] = None  # a description that is no readable spec: its CID instead
    page.goto(f"{server.url}/tasks")
    expect(page.locator("#tasks-table tbody tr")).to_have_count(3)
    row2 = page.locator('#tasks-table tr[data-task-id="2"]')
    expect(row2.locator(".env")).to_have_text("10×10 · 2 agents · 0 walls · 4 moves · I=1e9")
    expect(row2.locator(".reward")).to_have_text("0.005 ETH")
    expect(page.locator('#tasks-table tr[data-task-id="1"] .env')).to_contain_text("spec bafkrei")
