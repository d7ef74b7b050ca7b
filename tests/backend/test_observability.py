"""Gateway metrics (``GET /metrics``) and structured JSON logs."""

from __future__ import annotations

import io
import json
import logging
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from backend.api.main import create_app
from backend.db import models as m
from backend.observability.logs import JsonFormatter, _Ours, task_context
from backend.observability.metrics import metric_names
from backend.settings import Settings


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    with TestClient(create_app(Settings(data_dir=tmp_path / "data"), chain=False)) as c:
        yield c


def sample(text: str, name: str, **labels: str) -> float:
    """The value of sample ``name`` with exactly ``labels`` (0 when absent)."""
    for line in text.splitlines():
        if line.startswith("#"):
            continue
        m_ = re.match(r"^([a-zA-Z_:][\w:]*)(?:\{(.*)\})? (\S+)$", line)
        if not m_ or m_.group(1) != name:
            continue
        got = dict(re.findall(r'(\w+)="((?:[^"\\]|\\.)*)"', m_.group(2) or ""))
        if got == labels:
            return float(m_.group(3))
    return 0.0


def test_metrics_count_requests_by_route_template_and_errors(client: TestClient) -> None:
    before = client.get("/metrics")
    assert before.status_code == 200 and before.headers["content-type"].startswith("text/plain")
    route = "/api/tasks/{task_id}"
    n0 = sample(
        before.text,
        "drlaas_http_request_duration_seconds_count",
        method="GET",
        route=route,
        status="404",
    )
    for task_id in (11, 12, 13):  # three raw paths, one template
        assert client.get(f"/api/tasks/{task_id}").status_code == 404
    client.get("/api/health")
    after = client.get("/metrics").text
    count = sample(
        after, "drlaas_http_request_duration_seconds_count", method="GET", route=route, status="404"
    )
    assert count == n0 + 3
    assert 'route="/api/tasks/13"' not in after  # never the raw path
    assert sample(after, "drlaas_http_errors_total", method="GET", route=route, kind="client") >= 3
    health = sample(
        after,
        "drlaas_http_request_duration_seconds_count",
        method="GET",
        route="/api/health",
        status="200",
    )
    assert health >= 1
    names = set(metric_names(after))
    assert {"drlaas_http_request_duration_seconds_bucket", "drlaas_index_up"} <= names


def test_tasks_by_state_come_from_the_index(client: TestClient) -> None:
    assert sample(client.get("/metrics").text, "drlaas_tasks", state="open") == 0
    with client.app.state.sessions() as s:
        for i, status in enumerate(["open", "open", "completed"], start=1):
            s.add(
                m.TaskRow(
                    id=i,
                    requester="0x" + "1" * 40,
                    domain=0,
                    status=status,
                    num_workers=1,
                    reward_wei="0",
                    deadline=0,
                    min_reputation=0,
                    min_rating=0,
                    min_cpu_cores=0,
                    min_ram_gb=0,
                    description="x",
                    offered=0,
                    block_number=1,
                    updated_block=1,
                )
            )
        s.commit()
    text = client.get("/metrics").text
    assert sample(text, "drlaas_tasks", state="open") == 2
    assert sample(text, "drlaas_tasks", state="completed") == 1
    assert sample(text, "drlaas_index_up") == 1


def test_json_formatter_emits_one_object_per_line_with_task_id() -> None:
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(JsonFormatter())
    logger = logging.getLogger("drlaas.test.json")
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    logger.propagate = False
    try:
        logger.info("plain %s", "line")
        with task_context(42):
            logger.warning("inside a job\nwith a newline")
        logger.info("explicit", extra={"task_id": 7})
        try:
            raise ValueError("boom")
        except ValueError:
            logger.exception("failed")
    finally:
        logger.removeHandler(handler)
    lines = stream.getvalue().splitlines()
    docs = [json.loads(line) for line in lines]  # every line is one JSON object
    assert len(docs) == 4
    assert docs[0]["message"] == "plain line" and "task_id" not in docs[0]
    assert docs[1]["task_id"] == 42 and docs[1]["level"] == "WARNING"
    assert docs[1]["message"] == "inside a job\nwith a newline"
    assert docs[2]["task_id"] == 7 and docs[2]["logger"] == "drlaas.test.json"
    assert "ValueError: boom" in docs[3]["exception"]
    assert all(set(d) >= {"time", "level", "logger", "message"} for d in docs)


def test_gateway_requests_about_a_task_log_its_id(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    app = create_app(Settings(data_dir=tmp_path / "data", log_format="json"), chain=False)
    @app.get("/api/tasks/{task_id}/logtest")
    def logtest(task_id: int) -> dict[str, int]:
        logging.getLogger("drlaas.test.route").warning("about the task")
        return {"task_id": task_id}

    app.router.routes.insert(0, app.router.routes.pop())  # before the UI mount
    try:
        with TestClient(app) as c:
            assert c.get("/api/tasks/5/logtest").json() == {"task_id": 5}
        lines = [ln for ln in capsys.readouterr().err.splitlines() if "about the task" in ln]
        assert [json.loads(ln)["task_id"] for ln in lines] == [5]
    finally:  # leave the root logger as pytest set it up
        root = logging.getLogger()
        for h in [h for h in root.handlers if isinstance(h, _Ours)]:
            root.removeHandler(h)


def test_metrics_ask_for_their_token_when_one_is_set(tmp_path: Path) -> None:
    """DRLAAS_METRICS_TOKEN: only a scraper sending it reads the figures; the rest of the API
    is unchanged (the token is not an API credential)."""
    token = "scrape-" + "x" * 30
    settings = Settings(data_dir=tmp_path / "data", metrics_token=token)
    with TestClient(create_app(settings, chain=False)) as c:
        for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": token}):
            r = c.get("/metrics", headers=headers)
            assert r.status_code == 401, headers
            assert r.json()["detail"]["rule"] == "metrics_token_required"
            assert token not in r.text and "drlaas_" not in r.text
            assert r.headers["www-authenticate"].startswith("Bearer")
        ok = c.get("/metrics", headers={"Authorization": f"Bearer {token}"})
        assert ok.status_code == 200 and "drlaas_http_request_duration_seconds" in ok.text
        assert c.get("/api/health").status_code == 200
    with pytest.raises(ValueError, match="DRLAAS_METRICS_TOKEN must be at least 16"):
        Settings(data_dir=tmp_path / "data", metrics_token="short")
