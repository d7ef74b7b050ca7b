"""Held-out: the read API and the relay after transactions signed by anyone straight to the
contracts (no pydantic): a task description that is not UTF-8."""

from __future__ import annotations

from typing import Any

from fastapi.testclient import TestClient

from backend.services.chain import ChainService
from tests.indexer.test_heldout_direct_writes import NOT_UTF8, add_task_calldata

from .conftest import P, signed_in_outsider


def test_a_relayed_task_described_by_bytes_not_utf8_is_answered_and_listed(
    client: TestClient, service: ChainService, settings: Any
) -> None:
    """A requester relays (POST /tx) an addTask it signed whose description is not UTF-8: the
    answer is the mined receipt, its description with U+FFFD, and the task page shows it. Before,
    decoding the receipt raised: a 500 for a transaction that was mined (a client retrying
    it got nonce_mismatch), and the index stopped at its block."""
    me, headers = signed_in_outsider(client, service, settings)
    w3 = service.chain.w3

    def relay(tx: dict[str, Any]) -> Any:
        raw = "0x" + bytes(me.sign_transaction(tx).raw_transaction).hex()
        return client.post(f"{P}/tx", json={"raw": raw}, headers=headers)

    r = client.post(f"{P}/users/requesters", headers=headers)
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "sign_locally"
    unsigned = r.json()["detail"]["tx"]
    unsigned.pop("from")
    assert relay(unsigned).status_code == 200
    task_tx = {
        **{k: unsigned[k] for k in ("chainId", "maxFeePerGas", "maxPriorityFeePerGas")},
        "to": service.platform.tmc.address,
        "data": add_task_calldata(NOT_UTF8),
        "value": 10**12,
        "gas": 1_000_000,
        "nonce": w3.eth.get_transaction_count(me.address),
    }
    r = relay(task_tx)
    assert r.status_code == 200, r.text
    (added,) = [e["args"] for e in r.json()["events"] if e["name"] == "TaskAdded"]
    expected = NOT_UTF8.decode(errors="replace")
    assert added["description"] == expected

    page = client.get(f"{P}/tasks/{added['taskId']}")
    assert page.status_code == 200, page.text
    assert page.json()["description"] == expected
    listed = client.get(f"{P}/tasks", params={"requester": me.address}).json()["data"]
    assert [t["id"] for t in listed] == [added["taskId"]]
