"""Requests from the gateway probe of 2026-11-28 (evening): integers sent as true or "4",
fractions that truncation would move, non-finite extra metrics, and outcome manifests a worker
made unreadable. Each is a 4xx/502 naming the rule, or the exact value, never a 500."""

from __future__ import annotations

from fastapi.testclient import TestClient

from backend.store.bundle import canonical_json

from .conftest import P, addr, register, task_body

W = "0x" + "11" * 20
ENV = {"rows": 8, "cols": 8, "agents": 2, "max_steps": 50}


def test_integer_fields_refuse_booleans_and_numeric_strings(client, login, service) -> None:
    register(client, login, ["user1"], {})
    h = login("user1")
    cases = {
        "task review true": (f"{P}/tasks/999/reviews", {"worker": W, "review": True}),
        "task review '4'": (f"{P}/tasks/999/reviews", {"worker": W, "review": "4"}),
        "model review": (f"{P}/models/requests/999/reviews", {"model_id": True, "review": 3}),
        "model id '2'": (f"{P}/models/requests/999/reviews", {"model_id": "2", "review": 3}),
        "num_models true": (f"{P}/models/requests", {"env": ENV, "num_models": True}),
        "weights '1'": (f"{P}/models/requests", {"env": ENV, "weights": ["1"] * 6}),
    }
    for name, (url, body) in cases.items():
        r = client.post(url, json=body, headers=h)
        assert r.status_code == 422, (name, r.status_code, r.text)
        assert "a count is" in r.text, (name, r.text)


def test_fractions_reach_the_chain_to_the_nearest_millionth(client, login, service) -> None:
    register(client, login, ["user1"], {})
    r = client.post(f"{P}/tasks", json=task_body(min_reputation=0.0642, min_rating=0.0157),
                    headers=login("user1"))
    assert r.status_code == 201, r.text
    task = client.get(f"{P}/tasks/{r.json()['task_id']}").json()
    assert (task["min_reputation"], task["min_rating"]) == (0.0642, 0.0157)


def _accepted_task(client, login, service) -> tuple[int, str]:
    register(client, login, ["user1"], {"user3": {"cpu_cores": 16}})
    r = client.post(f"{P}/tasks", json=task_body(num_workers=1), headers=login("user1"))
    worker = addr(service, "user3")
    with service.lock:
        service.platform.tmc.transact("acceptOffer", r.json()["task_id"], sender=worker)
    return r.json()["task_id"], worker


def test_extra_progress_metrics_must_be_finite(client, login, service) -> None:
    tid, _ = _accepted_task(client, login, service)
    client.app.state.indexer.poll()
    h = {**login("user3"), "content-type": "application/json"}
    for step, raw in enumerate(["NaN", "Infinity", "-Infinity", "1e400"]):
        r = client.post(f"{P}/tasks/{tid}/progress", headers=h,
                        content=f'{{"step": {step}, "entropy": {raw}}}')
        assert r.status_code == 422 and "finite" in r.text, (raw, r.text)
    r = client.post(f"{P}/tasks/{tid}/progress", json={"step": 9, "entropy": 0.5}, headers=h)
    assert r.status_code == 201, r.text


def test_an_unreadable_outcome_manifest_is_a_502_naming_it(client, login, service) -> None:
    tid, worker = _accepted_task(client, login, service)
    store = client.app.state.store
    files = {n: {"cid": store.add(b"x" * 10), "size": 10}
             for n in ("model.safetensors", "model.json")}
    nested = store.add(b"[" * 30_000 + b"]" * 30_000)  # past json's recursion limit
    bad_sealed = store.add(canonical_json(
        {"format": "drlaas-bundle/1", "files": files, "sealed": ["model.safetensors"]}))
    for cid in (nested, bad_sealed):
        if cid == bad_sealed:  # a second task for the second outcome
            r = client.post(f"{P}/tasks", json=task_body(num_workers=1), headers=login("user1"))
            tid = r.json()["task_id"]
            with service.lock:
                service.platform.tmc.transact("acceptOffer", tid, sender=worker)
        with service.lock:
            service.platform.tmc.submit_outcome(worker, tid, cid)
        client.app.state.indexer.poll()
        with TestClient(client.app, raise_server_exceptions=False) as c:
            r = c.get(f"{P}/models/outcomes/{tid}/{worker}/download", headers=login("user1"))
        assert r.status_code == 502 and r.json()["detail"]["rule"] == "bundle_invalid", r.text
