"""Held-out data on the web UI (third pass, 2026-12-05), in headless Chromium against the fake
gateway and, for the axis labels, in Node: a description of one long word, a live-curve
point whose extra metrics name the chart's x key or a "rate" of 1e300, and axes of 1e12 steps.
Each test fails on the code before its fix (its docstring says what happened then)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from tests.frontend.conftest import LiveServer
from tests.frontend.fake_api import W1, FakeState

expect = pytest.importorskip("playwright.sync_api", reason="pip install playwright").expect

CHART = Path(__file__).resolve().parents[2] / "frontend" / "js" / "chart.js"
NODE = shutil.which("node")


def page_width_fits(page: Any) -> None:
    width = page.evaluate("document.documentElement.clientWidth")
    assert page.evaluate("document.documentElement.scrollWidth") <= width


@pytest.mark.parametrize("width", [360, 1280])
def test_a_description_of_one_long_word_does_not_widen_the_model_page(
    page: Any, server: LiveServer, state: FakeState, width: int
) -> None:
    """A description is 1,024 characters of the owner's choice: one word of them made the
    model page ~30,000 px wide (the list cut it; the page did not), on a desktop too."""
    state.models[0]["description"] = "ab" * 512
    page.set_viewport_size({"width": width, "height": 800})
    page.goto(f"{server.url}/models/1")
    expect(page.locator("#model-description")).to_have_text("ab" * 512)
    page_width_fits(page)


def test_extra_metrics_do_not_move_or_flatten_the_live_curve(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    """A worker's extra metrics are any finite numbers up to 1e300 under names it picks. One
    named ``global_step`` (which the chart reads before the gateway's ``step``) put every
    point of the live curve at ±1e300, and an ``eval_success`` of 1e300 stretched the success
    axis (a rate, 0 to 1) so that the training line lay flat on its floor."""
    state.task(1)["progress"] = [
        {"worker": W1, "step": 1000 * (i + 1), "success": 0.2 * i, "time": 9.0 - i,
         "cost": 12.0 - i, "extra": {"global_step": (-1) ** i * 1e300, "eval_success": 1e300}}
        for i in range(5)
    ]
    page.goto(f"{server.url}/tasks/1")
    chart = page.locator('#task-curve [data-chart="Success rate"]')
    expect(chart.locator("polyline")).to_have_count(1)  # the training line; no 1e300 "rate"
    xs = [float(p.split(",")[0])
          for p in chart.locator("polyline").get_attribute("points").split()]
    assert xs == sorted(xs) and len(set(xs)) == 5, xs  # steps 1000..5000, left to right
    ticks = chart.locator("text.tick").all_text_contents()
    assert "1" in ticks and not any("e" in t for t in ticks), ticks


@pytest.mark.skipif(NODE is None, reason="node is not installed")
def test_axis_labels_are_in_human_units() -> None:
    """Labels had k and M only: 1e12 steps read "1000000M", 3e300 "3e+294M", and ticks
    5e-5 apart all read "0"."""
    values = [0, 999, 1500, 2e6, 1e9, 2.5e11, 1e12, 2e15, -3e300, 5e-5, 0.5]
    script = (
        f"import {{ fmtTick }} from {json.dumps(CHART.as_uri())};\n"
        f"console.log(JSON.stringify({json.dumps(values)}.map(fmtTick)));\n"
    )
    done = subprocess.run([NODE or "node", "--input-type=module", "-e", script],
                          capture_output=True, text=True, timeout=20, check=True)
    assert json.loads(done.stdout) == [
        "0", "999", "1.5k", "2M", "1G", "250G", "1T", "2e15", "-3e300", "5e-5", "0.5"]


def test_a_timeline_status_is_named_only_for_the_contracts_codes(
    page: Any, server: LiveServer, state: FakeState
) -> None:
    """An event arg named ``status`` is shown as the TMC's TaskStatus name for its codes 0-4
    only. Looked up by any key, a direct write's (or a hostile index's) ``"constructor"``
    printed the source text of JavaScript's Array constructor, and ``"length"`` a 5."""
    from tests.frontend.fake_api import ALICE, event

    state.task(1)["timeline"] = [
        event("TaskStatusChanged", 20, {"taskId": 1, "requester": ALICE, "status": 2}),
        event("TaskStatusChanged", 21, {"taskId": 1, "requester": ALICE, "status": "constructor"}),
        event("TaskStatusChanged", 22, {"taskId": 1, "requester": ALICE, "status": "length"}),
    ]
    page.goto(f"{server.url}/tasks/1")
    timeline = page.locator("#task-timeline")
    expect(timeline).to_contain_text("completed")
    text = timeline.inner_text()
    assert "native code" not in text and "function" not in text, text
    assert "constructor" in text and "length" in text, text
