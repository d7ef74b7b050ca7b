"""A caller who signs addTask itself may have only a few task specs waiting in the store for a
task that is not on chain (backend/api/pending_specs.py; the 2026-12-03 audit: every unrelayed
POST /tasks left a spec behind, for free)."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from backend.api.pending_specs import PendingSpecs
from backend.errors import RateLimited
from backend.services.chain import ChainService

from .conftest import P, signed_in_outsider, task_body


def test_pending_specs_are_bounded_per_address_until_on_chain_or_old() -> None:
    now = [0.0]
    pending = PendingSpecs(per_address=2, window_s=100.0, clock=lambda: now[0])
    on_chain: set[str] = set()

    def indexed(cids: Any) -> set[str]:
        return on_chain & set(cids)

    for cid in ("a", "b"):
        pending.reserve("0xA", cid, indexed)
    with pytest.raises(RateLimited) as refused:
        pending.reserve("0xA", "b", indexed)  # the same spec again: still at the bound
    assert refused.value.rule == "too_many_pending_specs"
    assert refused.value.retry_after == pytest.approx(100.0)
    pending.reserve("0xB", "a", indexed)  # another address has its own bound
    on_chain.add("a")  # its task was added: no longer pending
    pending.reserve("0xA", "c", indexed)
    with pytest.raises(RateLimited):
        pending.reserve("0xA", "d", indexed)
    now[0] = 101.0  # "b" and "c" age out
    pending.reserve("0xA", "d", indexed)


def test_unrelayed_task_specs_stop_being_stored(
    client: TestClient, service: ChainService, settings: Any
) -> None:
    account, headers = signed_in_outsider(client, service, settings)

    def relay(answer: Any) -> None:
        assert answer.status_code == 409 and answer.json()["detail"]["rule"] == "sign_locally"
        tx = answer.json()["detail"]["tx"]
        tx.pop("from")
        raw = "0x" + bytes(account.sign_transaction(tx).raw_transaction).hex()
        r = client.post(f"{P}/tx", json={"raw": raw}, headers=headers)
        assert r.status_code == 200, r.text

    relay(client.post(f"{P}/users/requesters", headers=headers))
    client.app.state.pending_specs = PendingSpecs(per_address=2)  # type: ignore[attr-defined]
    store = client.app.state.store  # type: ignore[attr-defined]

    first = client.post(f"{P}/tasks", json=task_body(seed=1), headers=headers)
    second = client.post(f"{P}/tasks", json=task_body(seed=2), headers=headers)
    assert second.json()["detail"]["rule"] == "sign_locally"
    third = task_body(seed=3)
    pins = store.pins()
    r = client.post(f"{P}/tasks", json=third, headers=headers)
    assert r.status_code == 429, r.text
    assert store.pins() == pins  # refused before anything is stored
    assert r.json()["detail"]["rule"] == "too_many_pending_specs"
    assert "POST /api/tx" in r.json()["detail"]["msg"] and int(r.headers["Retry-After"]) > 0

    relay(first)  # its addTask on chain: the caller may store one more spec
    client.app.state.indexer.poll()  # type: ignore[attr-defined]
    r = client.post(f"{P}/tasks", json=third, headers=headers)
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "sign_locally", r.text
    assert _spec_cid(service, r) in set(store.pins()) - set(pins)


def _spec_cid(service: ChainService, answer: Any) -> str:
    """The spec CID an unsigned addTask names (its last argument)."""
    tmc = service.platform.tmc.contract
    _, args = tmc.decode_function_input(answer.json()["detail"]["tx"]["data"])
    params = args["p"]
    return str(params["description"] if isinstance(params, dict) else params[-1])
