"""Held-out probe of the gateway (fourth pass): an outcome file that is no UnixFS file, list
pages cached under repeated query parameters, misspelled fields of write bodies, and parallel
task posts racing past the bound on specs waiting for their ``addTask``. Each answered a 500,
another query's page, a transaction the caller did not ask for (an outcome paid instead of
rejected), or stored more specs than the bound."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest
from fastapi.testclient import TestClient

from backend.api.pending_specs import PendingSpecs
from backend.chain.platform import OfferState
from backend.services.chain import ChainService
from backend.store.bundle import canonical_json
from backend.store.cid import CID, DAG_PB
from backend.store.dag import UnixFSData, encode_pbnode

from .conftest import ENV, Login, P, addr, register, signed_in_outsider, task_body


def _accepted_task(client: TestClient, login: Login, service: ChainService) -> tuple[int, str]:
    register(client, login, ["user1"], {"user3": {"cpu_cores": 16}})
    r = client.post(f"{P}/tasks", json=task_body(num_workers=1), headers=login("user1"))
    assert r.status_code == 201, r.text
    task_id, worker = r.json()["task_id"], addr(service, "user3")
    with service.lock:
        service.platform.tmc.transact("acceptOffer", task_id, sender=worker)
    client.app.state.indexer.poll()  # type: ignore[attr-defined]
    return task_id, worker


def test_an_outcome_file_that_is_no_unixfs_file_is_a_502_naming_it(
    app: Any, login: Login, service: ChainService
) -> None:
    """A worker's outcome manifest may name, as its weights, a dag-pb block that is a UnixFS
    directory (or any node that is not a file): the store raises ``InvalidContent`` on the
    first read, which the outcome download did not catch, so the requester got a 500."""
    with TestClient(app, raise_server_exceptions=False) as client:
        task_id, worker = _accepted_task(client, login, service)
        store = client.app.state.store  # type: ignore[attr-defined]
        directory = encode_pbnode([], UnixFSData(type=1).encode())  # UnixFS type 1: directory
        dir_cid = CID.for_block(directory, DAG_PB)
        store._put_block(dir_cid, directory)
        card = store.add(b"{}")
        manifest = store.add(canonical_json({"format": "drlaas-bundle/1", "files": {
            "model.safetensors": {"cid": str(dir_cid), "size": 10},
            "model.json": {"cid": card, "size": 2},
        }}))
        with service.lock:
            service.platform.tmc.submit_outcome(worker, task_id, manifest)
        client.app.state.indexer.poll()  # type: ignore[attr-defined]
        r = client.get(f"{P}/models/outcomes/{task_id}/{worker}/download",
                       headers=login("user1"))
    assert r.status_code == 502, r.text
    detail = r.json()["detail"]
    assert detail["rule"] == "content_corrupt" and str(dir_cid) in detail["msg"], detail


def test_repeated_query_parameters_are_answered_with_the_value_the_route_reads(
    client: TestClient, login: Login
) -> None:
    """A route reads the last of a repeated query parameter (``?status=completed&status=open``
    lists open tasks), but the list-page cache keyed the parameters sorted: that request and
    ``?status=open&status=completed`` shared one key, so whichever came second was answered
    the first one's page."""
    register(client, login, ["user1"], {})
    r = client.post(f"{P}/tasks", json=task_body(), headers=login("user1"))
    assert r.status_code == 201, r.text
    assert client.get(f"{P}/tasks?status=open").json()["count"] == 1
    for _ in range(2):  # in both orders, each query keeps its own answer
        assert client.get(f"{P}/tasks?status=open&status=completed").json()["count"] == 0
        assert client.get(f"{P}/tasks?status=completed&status=open").json()["count"] == 1
    assert client.get(f"{P}/models?sort=newest&limit=1&limit=2").status_code == 200


def test_a_misspelled_review_field_is_refused_not_read_as_the_default(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """``{"worker", "review": 0, "accept": false}`` (for ``accepted``) was read as
    ``accepted: true``, the default: the requester meaning to reject an outcome paid its worker,
    which no one can undo. Unknown fields of write bodies are now a 422 naming them, and
    nothing is sent."""
    task_id, worker = _accepted_task(client, login, service)
    outcome = client.app.state.store.add(b"an outcome")  # type: ignore[attr-defined]
    with service.lock:
        service.platform.tmc.submit_outcome(worker, task_id, outcome)
    r = client.post(f"{P}/tasks/{task_id}/reviews", headers=login("user1"),
                    json={"worker": worker, "review": 0, "accept": False})
    assert r.status_code == 422, r.text
    (issue,) = r.json()["detail"]
    assert issue["loc"] == ["body", "accept"] and issue["type"] == "extra_forbidden", issue
    state, _, _, paid = service.platform.tmc.call("getOffer", task_id, worker)
    assert int(state) != OfferState.REVIEWED and not paid


@pytest.mark.parametrize(
    ("url", "body"),
    [
        (f"{P}/models/requests", {"env": ENV, "num_model": 3}),  # paid for 1 model
        (f"{P}/models/requests", {"env": ENV, "min_model_reputaton": 0.9}),  # any model
        (f"{P}/models/requests/1/reviews", {"model_id": 1, "review": 5, "note": "x"}),
        (f"{P}/users/workers", {"domains": [0], "cpu_cores": 4, "ram_gb": 8, "gpu": 3}),
        (f"{P}/models", {"cid": "bafkreihdwdcefgh4dqkjv67uzcmw7ojee6xedzdetojuzjevtenxquvyku",
                         "env": ENV, "descripton": "mine"}),
        (f"{P}/tx", {"raw": "0x00", "wait": False}),
        (f"{P}/auth/nonce", {"address": "0x7E5F4552091A69125d5DfCb7b8C2659029395Bdf",
                             "chain_id": 1}),
    ],
)
def test_unknown_fields_of_write_bodies_are_refused(
    client: TestClient, login: Login, url: str, body: dict[str, Any]
) -> None:
    register(client, login, ["user1"], {"user3": {}})
    who = "user3" if url.endswith(("/workers", "/models")) else "user1"
    blocks = client.app.state.chain.block_number()  # type: ignore[attr-defined]
    r = client.post(url, json=body, headers=login(who))
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert isinstance(detail, list), detail  # the validation shape, not a rule of the route
    extra = [i for i in detail if i["type"] == "extra_forbidden"]
    assert extra and extra[0]["loc"][0] == "body", r.text
    assert client.app.state.chain.block_number() == blocks  # type: ignore[attr-defined]


def test_parallel_task_posts_cannot_pass_the_pending_spec_bound_together(
    client: TestClient, service: ChainService, settings: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A caller who signs ``addTask`` itself may have ``per_address`` specs stored waiting for
    their task. The bound was checked, then the spec stored, then counted, each apart: posts
    sent in parallel all passed the check before any was counted (one address stored as many
    specs as it sent requests at once). Now the check counts the spec in the same step."""
    account, headers = signed_in_outsider(client, service, settings)
    r = client.post(f"{P}/users/requesters", headers=headers)
    tx = r.json()["detail"]["tx"]
    tx.pop("from")
    raw = "0x" + bytes(account.sign_transaction(tx).raw_transaction).hex()
    assert client.post(f"{P}/tx", json={"raw": raw}, headers=headers).status_code == 200
    client.app.state.pending_specs = PendingSpecs(per_address=1)  # type: ignore[attr-defined]
    store = client.app.state.store  # type: ignore[attr-defined]
    both_checked = threading.Barrier(2, timeout=3)
    add = store.add

    def add_when_both_checked(data: bytes, **kw: Any) -> str:
        try:  # the two posts meet here only if both passed the bound before either stored
            both_checked.wait()
        except threading.BrokenBarrierError:
            pass
        return add(data, **kw)

    monkeypatch.setattr(store, "add", add_when_both_checked)
    with ThreadPoolExecutor(2) as pool:
        answers = list(pool.map(
            lambda seed: client.post(f"{P}/tasks", json=task_body(seed=seed), headers=headers),
            (1, 2),
        ))
    rules = sorted(a.json()["detail"]["rule"] for a in answers)
    assert rules == ["sign_locally", "too_many_pending_specs"], [a.text for a in answers]


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-le", "utf-32-be"])
def test_a_body_in_utf16_or_utf32_is_refused_before_its_bounds_are_scanned(
    app: Any, encoding: str
) -> None:
    """Python's JSON parser reads a bytes body in UTF-16 or UTF-32 too, but the body bounds
    scan bytes as UTF-8: in UTF-16 an escaped quote (``\\"`` is ``\\ NUL " NUL``) ended the
    string the scan skips, so 100,000 brackets after it hid in a "string" and a 5,000-digit
    number had NULs between its digits. An anonymous ``POST /rpc`` of such a body answered 500
    (RecursionError; ValueError past 4,300 digits), a route of ``/api`` a bare 400 "error
    parsing the body". JSON between systems is UTF-8 (RFC 8259, 8.1): anything else is a 415
    naming the rule, before any parsing (documented on every operation with a body)."""
    json_ = {"content-type": "application/json"}
    deep = '["\\"", ' + "[" * 100_000 + "]" * 100_000 + "]"
    long = '{"jsonrpc": "2.0", "id": 1, "method": "eth_chainId", "n": ' + "7" * 5000 + "}"
    nonce = '{"address": "0x7E5F4552091A69125d5DfCb7b8C2659029395Bdf"}'
    with TestClient(app, raise_server_exceptions=False) as client:
        for url, text in (("/rpc", deep), ("/rpc", long), (f"{P}/auth/nonce", nonce)):
            r = client.post(url, content=text.encode(encoding), headers=json_)
            assert r.status_code == 415, (url, r.text)
            detail = r.json()["detail"]
            assert detail["rule"] == "json_not_utf8" and "UTF-8" in detail["msg"], detail
        # UTF-8, with or without its byte order mark, is read as before
        for body in (nonce.encode(), b"\xef\xbb\xbf" + nonce.encode()):
            r = client.post(f"{P}/auth/nonce", content=body, headers=json_)
            assert r.status_code == 200, r.text
        spec = client.get(f"{P}/openapi.json").json()
    for path, method in ((f"{P}/auth/nonce", "post"), ("/rpc", "post"), (f"{P}/tx", "post")):
        assert "415" in spec["paths"][path][method]["responses"], (path, method)


def test_head_of_a_get_resource_answers_its_headers_without_a_body(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """``HEAD`` of every ``GET`` route was 405 (FastAPI routes GET only): an uptime monitor's
    ``HEAD /api/health`` failed, and a client could not ask a download's size. Now it is the
    GET's status and headers, no body; a download's HEAD reads no file and takes no slot."""
    r = client.head(f"{P}/health")
    assert r.status_code == 200 and r.content == b"", r.text
    assert r.headers["content-type"] == "application/json"
    assert r.headers["x-content-type-options"] == "nosniff"  # the security headers too
    assert client.head(f"{P}/tasks/999").status_code == 404
    r = client.head(f"{P}/tx")  # a POST route: 405 as for GET, naming what it allows
    assert r.status_code == 405 and r.headers["allow"] == "POST", r.headers
    task_id, worker = _accepted_task(client, login, service)
    store = client.app.state.store  # type: ignore[attr-defined]
    weights = b"w" * 3000
    manifest = store.add(canonical_json({"format": "drlaas-bundle/1", "files": {
        "model.safetensors": {"cid": store.add(weights), "size": len(weights)},
        "model.json": {"cid": store.add(b"{}"), "size": 2},
    }}))
    with service.lock:
        service.platform.tmc.submit_outcome(worker, task_id, manifest)
    client.app.state.indexer.poll()  # type: ignore[attr-defined]
    url = f"{P}/models/outcomes/{task_id}/{worker}/download"
    r = client.head(url, headers=login("user1"))
    assert r.status_code == 200 and r.content == b"", r.text
    assert r.headers["content-length"] == str(len(weights))
    assert r.headers["x-content-cid"] == store.add(weights)
    assert client.app.state.download_pool.total == 0  # type: ignore[attr-defined]
    assert client.get(url, headers=login("user1")).content == weights
