"""Events the index kept without their rows (``chain_events.error``) are visible through the
API: on the task's timeline, counted by ``/api/health`` and listed at
``/api/health/index-errors``; before, only the database showed why a listing lacked them."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from backend.indexer import Indexer

from .conftest import Login, P, register, task_body


def test_an_event_kept_without_its_rows_is_shown_with_its_error(
    client: TestClient, login: Login, monkeypatch: pytest.MonkeyPatch
) -> None:
    def unstorable(self: Indexer, s: Any, a: dict[str, Any], block: int) -> None:
        raise ValueError(f"qos {a['qos']} out of range")

    monkeypatch.setattr(Indexer, "_on_TaskOffered", unstorable)
    register(client, login, ["user1"], {"user3": {"cpu_cores": 16}})
    assert client.get(f"{P}/health").json()["index_errors"] == 0
    r = client.post(f"{P}/tasks", json=task_body(num_workers=1), headers=login("user1"))
    assert r.status_code == 201, r.text
    client.app.state.indexer.poll()  # type: ignore[attr-defined]

    timeline = client.get(f"{P}/tasks/{r.json()['task_id']}").json()["timeline"]
    errors = {e["name"]: e["error"] for e in timeline}
    assert errors["TaskAdded"] is None
    assert errors["TaskOffered"].startswith("ValueError: qos ")

    assert client.get(f"{P}/health").json()["index_errors"] == 1
    listed = client.get(f"{P}/health/index-errors").json()
    assert listed["count"] == 1
    (event,) = listed["data"]
    assert event["name"] == "TaskOffered" and event["error"] == errors["TaskOffered"]
    assert event["args"]["taskId"] == r.json()["task_id"]
    assert client.get(f"{P}/health/index-errors", params={"offset": 1}).json()["data"] == []
    assert client.get(f"{P}/health/index-errors", params={"limit": 0}).status_code == 422
