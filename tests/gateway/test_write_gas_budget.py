"""A remote client's /api writes draw what they execute under the chain lock from its /rpc gas
budget: the estimate of a transaction handed back to sign (``sign_locally``) and a relayed one.

Before, asking again and again for an unsigned ``allocateTask`` ran eth-tester's gas bisection
(~25 executions of the whole recruitment) under the lock for free, stalling every other chain
access for tens of seconds (docs/platform.md, "Gas budgets")."""

from __future__ import annotations

from typing import Any

import pytest
from eth_account import Account
from fastapi.testclient import TestClient

from backend.auth import DemoKeys, bearer_headers
from backend.services import rpc_call
from backend.services.chain import ChainService
from backend.services.rpc_budget import GasBudget

from .conftest import P, signed_in_outsider


def test_sign_locally_estimates_are_bounded_and_drawn_from_the_clients_budget(
    client: TestClient, service: ChainService, settings: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    account, headers = signed_in_outsider(client, service, settings)
    executions: list[int] = []
    real_execute = rpc_call._execute

    def counted(tester: Any, tx: dict[str, Any], block: Any, gas: int) -> Any:
        executions.append(gas)
        return real_execute(tester, tx, block, gas)

    monkeypatch.setattr(rpc_call, "_execute", counted)
    rpc = client.app.state.rpc  # type: ignore[attr-defined]
    now = [0.0]  # the bucket's clock stands still unless the test moves it
    # this client's bucket: one execution at the cap (checked up front) and a few estimates
    rpc.budget = GasBudget(per_minute=rpc.gas_cap + 400_000, clock=lambda: now[0])

    r = client.post(f"{P}/users/requesters", headers=headers)
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "sign_locally", r.text
    assert 1 <= len(executions) <= rpc_call.ESTIMATE_PROBES  # not a bisection from 30M gas
    tx = r.json()["detail"]["tx"]
    assert tx["from"] == account.address and tx["gas"] > 21_000

    answers = [client.post(f"{P}/users/requesters", headers=headers) for _ in range(40)]
    refused = [a for a in answers if a.status_code == 429]
    assert refused, "the client's budget never ran out"
    body = refused[0].json()["detail"]
    assert body["rule"] == "gas_budget_used" and "retry in" in body["msg"]
    assert int(refused[0].headers["Retry-After"]) >= 1
    # once refused, nothing more is executed for this client until its bucket refills
    ran = len(executions)
    assert client.post(f"{P}/users/requesters", headers=headers).status_code == 429
    assert len(executions) == ran

    # a relayed transaction runs under the lock too: it draws its gas limit, as on /rpc
    tx.pop("from")
    raw = "0x" + bytes(account.sign_transaction(tx).raw_transaction).hex()
    rpc.budget = GasBudget(per_minute=tx["gas"] - 1, clock=lambda: now[0])
    r = client.post(f"{P}/tx", json={"raw": raw}, headers=headers)
    assert r.status_code == 429 and r.json()["detail"]["rule"] == "gas_budget_used"
    rpc.budget = GasBudget(per_minute=tx["gas"], clock=lambda: now[0])
    r = client.post(f"{P}/tx", json={"raw": raw}, headers=headers)
    assert r.status_code == 200, r.text
    assert service.platform.umc.call("isRequester", account.address)


def test_a_revert_found_by_the_bounded_estimate_is_the_contracts_rule(
    client: TestClient, service: ChainService, settings: Any
) -> None:
    """The metered estimate still reports the contract's typed error, not a 500."""
    _, headers = signed_in_outsider(client, service, settings)
    r = client.post(f"{P}/tasks/999/allocate", headers=headers)
    assert r.status_code in (403, 404, 409), r.text
    assert r.json()["detail"]["rule"] != "sign_locally"


def test_an_unfunded_key_gets_no_transaction_to_sign(
    client: TestClient, settings: Any
) -> None:
    """The unpriced estimate charges no fee, so the balance is checked on its own."""
    poor = Account.create()
    keys = DemoKeys(settings)
    keys.add("poor", poor)
    r = client.post(
        f"{P}/users/requesters", headers=dict(bearer_headers(keys.sign_in(client, "poor")))
    )
    assert r.status_code == 402 and r.json()["detail"]["rule"] == "insufficient_funds"
