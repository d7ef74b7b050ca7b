"""The UI against the real gateway (``create_app``), once its resource routes exist: every page
loads its data from the real API without a script error or an error box."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from backend.api.frontend import mount_frontend
from backend.api.main import create_app
from backend.settings import Settings
from tests.frontend.conftest import LiveServer

expect = pytest.importorskip("playwright.sync_api", reason="pip install playwright").expect

NEEDED = ("/api/models", "/api/tasks", "/api/workers")


def test_pages_load_from_the_real_gateway(page: Any, tmp_path: Path) -> None:
    app = create_app(Settings(data_dir=tmp_path / "data"))
    paths = set(app.openapi()["paths"])
    missing = [p for p in NEEDED if p not in paths]
    if missing:
        pytest.skip(f"the gateway has no {', '.join(missing)} route yet (backend/api/routes/)")
    if not any(getattr(r, "name", "") == "frontend" for r in app.routes):
        mount_frontend(app)
    with LiveServer(app) as server:
        for path, ready in (
            ("/models", "#models-table, #no-models"),
            ("/tasks", "#tasks-table, #no-tasks"),
            ("/workers", "#workers-table, #no-workers"),
            ("/submit", "#task-form"),
        ):
            page.goto(server.url + path)
            expect(page.locator(ready).first).to_be_visible()
            expect(page.locator(".error-box")).to_have_count(0)
            if path == "/models":  # a new platform: nothing shared, not "no match"
                expect(page.locator("#no-models")).to_contain_text("No model shared yet")
        # the form reads its bounds from the real document (the page stays on /submit)
        expect(page.locator("#task-form")).to_have_attribute("data-bounds", "openapi")
        body = app.openapi()["components"]["schemas"]["TaskCreate"]["properties"]
        for selector, schema in (
            ("#f-num_workers", body["num_workers"]),
            ("#f-env-rows", body["env"]["properties"]["rows"]),
            ("#f-observation-window", body["observation"]["properties"]["window"]),
        ):
            assert float(page.locator(selector).get_attribute("max")) == schema["maximum"]


def test_a_pending_requester_is_told_to_wait_for_approval(page: Any, tmp_path: Path) -> None:
    """On a chain that approves requesters (a consortium), the submit page registers the user
    and says an admin must approve it; submitting again names the wait, not registration."""
    app = create_app(Settings(data_dir=tmp_path / "data"))
    if not any(getattr(r, "name", "") == "frontend" for r in app.routes):
        mount_frontend(app)
    with LiveServer(app) as server:
        service = app.state.chain
        with service.lock:
            service.platform.umc.set_approval_required(service.platform.admin, True)
        page.goto(server.url + "/submit")
        page.select_option("#demo-user", label="user3")
        page.click("#demo-sign-in")
        page.fill("#f-env-agents", "2")
        page.fill("#f-env-rows", "6")
        page.fill("#f-env-cols", "6")
        page.click("#submit-task")
        expect(page.locator('[data-rule="tasks_not_requester"]')).to_be_visible()
        page.click("#register-requester")
        expect(page.get_by_text("a consortium admin must approve you")).to_be_visible()
        page.click("#submit-task")
        expect(page.locator('[data-rule="requester_pending"]')).to_be_visible()
        expect(page.locator("#register-requester")).to_have_count(0)
