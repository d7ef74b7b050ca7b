"""Findings of the gateway audit of 2026-12-03: chain-bound fields that took true or "4" for a
number (or 0 for a flag), path ids with many spellings, metric names with control and bidi
characters, a relayed transaction with a nonce gap that held the chain lock for 120 s, log
filters whose block tags leaked a Python exception, and two wrong status codes."""

from __future__ import annotations

from typing import Any

import pytest
from eth_account import Account
from fastapi.testclient import TestClient
from web3.exceptions import TimeExhausted

from backend.auth import DemoKeys, bearer_headers
from backend.services.chain import ChainService

from .conftest import ENV, Login, P, addr, fund, register, task_body


def _refused(r: Any, field: str) -> None:
    """A 422 whose validation issue names ``field``."""
    assert r.status_code == 422, r.text
    locs = [issue["loc"] for issue in r.json()["detail"]]
    assert any(field in loc for loc in locs), (field, r.text)


def test_task_and_request_numbers_refuse_booleans_and_strings(
    client: TestClient, login: Login
) -> None:
    register(client, login, ["user1"], {})
    h = login("user1")
    for field, value in [
        ("payment_wei", "1000000000000000"),
        ("payment_wei", True),
        ("min_reputation", "0.5"),
        ("min_reputation", True),
        ("min_rating", False),
        ("expert_allocation", True),
        ("expert_allocation", "1"),
    ]:
        _refused(client.post(f"{P}/tasks", json=task_body(**{field: value}), headers=h), field)
    for field, value in [
        ("price_wei", "1000000000000"),
        ("price_wei", True),
        ("min_reputation", "0.1"),
        ("min_model_reputation", True),
    ]:
        r = client.post(f"{P}/models/requests", json={"env": ENV, field: value}, headers=h)
        _refused(r, field)
    # the JSON numbers themselves still pass
    r = client.post(f"{P}/tasks", json=task_body(min_reputation=0.5, payment_wei=10**15),
                    headers=h)
    assert r.status_code == 201, r.text


@pytest.mark.parametrize("path", ["1.0", "%201", "1%20", "+1", "01e0", "%D9%A1"])
def test_path_ids_are_digits_only(client: TestClient, login: Login, path: str) -> None:
    register(client, login, ["user1"], {"user3": {"cpu_cores": 16}})
    assert client.post(f"{P}/tasks", json=task_body(num_workers=1),
                       headers=login("user1")).status_code == 201
    assert client.get(f"{P}/tasks/1").status_code == 200
    for url in (f"{P}/tasks/{path}", f"{P}/models/{path}", f"{P}/models/requests/{path}"):
        r = client.get(url)
        assert r.status_code == 422, (url, r.status_code, r.text)


def _accepted_task(client: TestClient, login: Login, service: ChainService) -> tuple[int, str]:
    register(client, login, ["user1"], {"user3": {"cpu_cores": 16}})
    r = client.post(f"{P}/tasks", json=task_body(num_workers=1), headers=login("user1"))
    worker = addr(service, "user3")
    with service.lock:
        service.platform.tmc.transact("acceptOffer", r.json()["task_id"], sender=worker)
    client.app.state.indexer.poll()  # type: ignore[attr-defined]
    return r.json()["task_id"], worker


def test_progress_and_review_types_and_metric_names(
    client: TestClient, login: Login, service: ChainService
) -> None:
    tid, worker = _accepted_task(client, login, service)
    h = login("user3")
    url = f"{P}/tasks/{tid}/progress"
    _refused(client.post(url, json={"step": "2"}, headers=h), "step")
    _refused(client.post(url, json={"step": True}, headers=h), "step")
    _refused(client.post(url, json={"step": 3, "success": True}, headers=h), "success")
    _refused(client.post(url, json={"step": 4, "success": "0.5"}, headers=h), "success")
    _refused(client.post(url, json={"step": 4, "cost": False}, headers=h), "cost")
    for name in ("\u0000\u202e<script>", "a\u202eb", "x\x7f", "zero\u200bwidth"):
        r = client.post(url, json={"step": 5, name: 1}, headers=h)
        assert r.status_code == 422, (name, r.text)
        assert "extra metric name" in r.text and "U+" in r.text, r.text
    r = client.post(url, json={"step": 5, "success": 0.5, "entropy é": 1}, headers=h)
    assert r.status_code == 201, r.text

    review = f"{P}/tasks/{tid}/reviews"
    for accepted in ("yes", 0, 1, "true"):
        r = client.post(review, json={"worker": worker, "review": 5, "accepted": accepted},
                        headers=login("user1"))
        _refused(r, "accepted")


def test_relayed_nonce_gap_is_refused_before_sending(
    client: TestClient, service: ChainService, settings: Any
) -> None:
    """A nonce past the sender's next one would sit in a node's queue, never mined, while the
    relay waited for its receipt: 409 ``nonce_mismatch`` naming both nonces, nothing sent."""
    me = Account.create()
    fund(service, me.address)
    own = DemoKeys(settings)
    own.add("me", me)
    headers = dict(bearer_headers(own.sign_in(client, "me")))
    r = client.post(f"{P}/users/requesters", headers=headers)
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "sign_locally"
    unsigned = r.json()["detail"]["tx"]
    unsigned.pop("from")
    block = service.block_number()
    gap = {**unsigned, "nonce": unsigned["nonce"] + 5}
    raw = "0x" + bytes(me.sign_transaction(gap).raw_transaction).hex()
    r = client.post(f"{P}/tx", json={"raw": raw}, headers=headers)
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "nonce_mismatch", r.text
    msg = r.json()["detail"]["msg"]
    nonce = unsigned["nonce"]
    assert f"nonce is {nonce + 5}" in msg and f"next nonce is {nonce}" in msg, msg
    assert service.block_number() == block  # nothing was sent
    # a max fee below the base fee: 422 before sending
    cheap = {**unsigned, "maxFeePerGas": 1, "maxPriorityFeePerGas": 0}
    raw = "0x" + bytes(me.sign_transaction(cheap).raw_transaction).hex()
    r = client.post(f"{P}/tx", json={"raw": raw}, headers=headers)
    assert r.status_code == 422 and r.json()["detail"]["rule"] == "fee_too_low", r.text
    assert service.block_number() == block
    # a gas limit above the relay's cap (the embedded chain executes under the platform lock)
    greedy = {**unsigned, "gas": settings.rpc_gas_cap + 1}
    raw = "0x" + bytes(me.sign_transaction(greedy).raw_transaction).hex()
    r = client.post(f"{P}/tx", json={"raw": raw}, headers=headers)
    assert r.status_code == 422 and r.json()["detail"]["rule"] == "tx_gas_cap", r.text
    assert str(settings.rpc_gas_cap) in r.json()["detail"]["msg"]
    assert service.block_number() == block
    # the receipt that does not come in time: 504 tx_pending with the hash, not a 500
    w3 = service.chain.w3

    def never(tx_hash: Any, timeout: float = 0, poll_latency: float = 0) -> Any:
        raise TimeExhausted("not mined")

    raw = "0x" + bytes(me.sign_transaction(unsigned).raw_transaction).hex()
    original = w3.eth.wait_for_transaction_receipt
    w3.eth.wait_for_transaction_receipt = never  # type: ignore[method-assign]
    try:
        with TestClient(client.app, raise_server_exceptions=False) as c:
            r = c.post(f"{P}/tx", json={"raw": raw}, headers=headers)
    finally:
        w3.eth.wait_for_transaction_receipt = original  # type: ignore[method-assign]
    assert r.status_code == 504 and r.json()["detail"]["rule"] == "tx_pending", r.text
    tx_hash = "0x" + bytes(w3.keccak(hexstr=raw)).hex()
    assert tx_hash in r.json()["detail"]["msg"]


def _rpc(client: TestClient, method: str, *params: Any) -> dict[str, Any]:
    r = client.post("/rpc", json={"jsonrpc": "2.0", "id": 1, "method": method,
                                  "params": list(params)})
    assert r.status_code == 200, r.text
    return r.json()


def test_log_filter_tags_and_bad_fields(client: TestClient, service: ChainService) -> None:
    """"safe" and "finalized" are the head on a chain with no forks (they raised a Python
    ValueError through to the client); a malformed field is -32602 naming it."""
    every = _rpc(client, "eth_getLogs", {"fromBlock": "0x0", "toBlock": "latest"})["result"]
    assert every
    head = _rpc(client, "eth_getLogs", {"fromBlock": "latest"})["result"]
    for tag in ("safe", "finalized", "pending"):
        assert _rpc(client, "eth_getLogs", {"fromBlock": "0x0", "toBlock": tag})["result"] == every
        assert _rpc(client, "eth_getLogs", {"fromBlock": tag})["result"] == head
    earliest = _rpc(client, "eth_getLogs", {"fromBlock": "earliest", "toBlock": "finalized"})
    assert earliest["result"] == every
    for flt, field in [
        ({"fromBlock": "0xzz"}, "fromBlock"),
        ({"toBlock": True}, "toBlock"),
        ({"address": 5}, "address"),
        ({"address": [service.platform.umc.address, "0x12"]}, "address"),
        ({"topics": "x"}, "topics"),
        ({"topics": [None, [5]]}, "topics"),
        ({"topics": [None] * 5}, "topics"),
    ]:
        err = _rpc(client, "eth_getLogs", flt)["error"]
        assert err["code"] == -32602 and field in err["message"], (flt, err)
        assert "Error" not in err["message"], err


def test_review_of_an_unknown_allocation_is_404(client: TestClient, login: Login) -> None:
    register(client, login, ["user1"], {})
    r = client.post(f"{P}/models/requests/999/reviews", json={"model_id": 1, "review": 5},
                    headers=login("user1"))
    assert r.status_code == 404 and r.json()["detail"]["rule"] == "allocation_not_found", r.text


def test_a_removed_worker_cannot_update_its_capabilities(
    client: TestClient, login: Login, service: ChainService, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Refused by the gateway from the worker's status on chain, nothing sent (or estimated)."""
    register(client, login, [], {"user3": {"cpu_cores": 16}})
    me = addr(service, "user3")
    h = login("user3")
    r = client.delete(f"{P}/users/workers/{me}", headers=h)
    assert r.status_code == 200, r.text
    sent: list[str] = []
    send = service.send

    def recorded(sender: str, handle: Any, fn: str, *args: Any, **kw: Any) -> Any:
        sent.append(fn)
        return send(sender, handle, fn, *args, **kw)

    monkeypatch.setattr(service, "send", recorded)
    body = {"domains": [0], "cpu_cores": 64, "ram_gb": 8, "gpu_series": 0}
    r = client.post(f"{P}/users/workers", json=body, headers=h)
    assert sent == [], sent
    assert r.status_code == 403 and r.json()["detail"]["rule"] == "users_not_approved", r.text
    assert service.platform.umc.call("getWorker", me)[1] == 4  # still removed
    assert 64 not in tuple(service.platform.umc.call("getWorker", me))
