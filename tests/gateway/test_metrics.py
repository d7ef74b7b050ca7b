"""``GET /metrics`` of a gateway with its chain: chain request latency and tasks by state move
with the platform's work."""

from __future__ import annotations

from fastapi.testclient import TestClient

from tests.backend.test_observability import sample

from .conftest import Login, P, register, task_body


def chain_requests(text: str) -> float:
    return sum(
        float(line.rsplit(" ", 1)[1])
        for line in text.splitlines()
        if line.startswith("drlaas_chain_request_duration_seconds_count{")
    )


def test_chain_latency_and_tasks_by_state(client: TestClient, login: Login) -> None:
    before = client.get("/metrics").text
    register(client, login, ["user1"], {"user2": {}})
    r = client.post(f"{P}/tasks", json=task_body(num_workers=1), headers=login("user1"))
    assert r.status_code == 201, r.text
    after = client.get("/metrics").text
    assert chain_requests(after) > chain_requests(before)  # the writes went to the chain
    assert 'method="eth_sendRawTransaction"' in after or 'method="eth_sendTransaction"' in after
    assert (
        sample(after, "drlaas_tasks", state="open")
        == sample(before, "drlaas_tasks", state="open") + 1
    )
    assert sample(after, "drlaas_offers", state="offered") >= 1
