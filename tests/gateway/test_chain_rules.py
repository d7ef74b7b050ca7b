"""Chain-side failures answered as 4xx naming the rule: the anti-spam minimum reward checked
before sending, an unfunded sender (402), a replayed transaction (409), a contract revert."""

from __future__ import annotations

from typing import Any

import pytest
from eth_abi import abi, encode
from eth_account import Account
from fastapi.testclient import TestClient

from backend.api.errors import domain_status
from backend.auth import DemoKeys, bearer_headers
from backend.chain import errors
from backend.services.chain import ChainService, node_rule_error

from .conftest import Login, P, addr, fund, register, task_body


def test_reward_below_minimum_is_422_before_sending(
    client: TestClient, login: Login, service: ChainService
) -> None:
    register(client, login, ["user1"], {"user3": {}})
    tmc = service.platform.tmc
    per_hour = tmc.call("minRewardPerHour")
    assert per_hour > 0  # the embedded deployment sets the settings' default
    before, block = tmc.call("taskCount"), service.block_number()
    minimum = tmc.min_reward(7_200)
    assert minimum == 2 * per_hour
    for payment in (0, minimum - 1):
        body = task_body(payment_wei=payment, deadline_s=7_200)
        r = client.post(f"{P}/tasks", json=body, headers=login("user1"))
        assert r.status_code == 422, r.text
        [issue] = r.json()["detail"]
        assert issue["loc"] == ["body", "payment_wei"] and issue["type"] == "reward_below_minimum"
        assert str(minimum) in issue["msg"]
    assert tmc.call("taskCount") == before and service.block_number() == block  # nothing sent
    body = task_body(payment_wei=minimum, deadline_s=7_200)
    assert client.post(f"{P}/tasks", json=body, headers=login("user1")).status_code == 201


def test_value_beyond_balance_is_402(client: TestClient, login: Login) -> None:
    register(client, login, ["user1"], {})
    body = task_body(payment_wei=10**28, num_workers=16)  # far above the demo balance
    r = client.post(f"{P}/tasks", json=body, headers=login("user1"))
    assert r.status_code == 402, r.text
    assert r.json()["detail"]["rule"] == "insufficient_funds"


def test_unfunded_key_and_replayed_tx(
    client: TestClient, service: ChainService, settings: Any
) -> None:
    """An unfunded account gets 402 instead of a transaction it could never pay for; a relayed
    transaction sent twice is a 409 nonce conflict."""
    poor = Account.create()
    own = DemoKeys(settings)
    own.add("poor", poor)
    headers = dict(bearer_headers(own.sign_in(client, "poor")))
    r = client.post(f"{P}/users/requesters", headers=headers)
    assert r.status_code == 402, r.text
    assert r.json()["detail"]["rule"] == "insufficient_funds"
    assert "b'" not in r.json()["detail"]["msg"]  # the node's bytes reprs shown as hex

    fund(service, poor.address)  # then relay its registration twice
    r = client.post(f"{P}/users/requesters", headers=headers)
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "sign_locally"
    unsigned = r.json()["detail"]["tx"]
    unsigned.pop("from")
    raw = "0x" + bytes(poor.sign_transaction(unsigned).raw_transaction).hex()
    assert client.post(f"{P}/tx", json={"raw": raw}, headers=headers).status_code == 200
    r = client.post(f"{P}/tx", json={"raw": raw}, headers=headers)
    assert r.status_code == 409, r.text
    assert r.json()["detail"]["rule"] == "nonce_mismatch"


def test_node_messages_map_to_rules() -> None:
    """Messages of JSON-RPC nodes (geth/anvil wording) map like eth-tester's."""
    cases = {
        "insufficient funds for gas * price + value: have 0 want 10": (402, "insufficient_funds"),
        "nonce too low: next nonce 5, tx nonce 4": (409, "nonce_mismatch"),
        "intrinsic gas too low: have 21000, want 53000": (422, "intrinsic_gas_too_low"),
        "max fee per gas less than block base fee": (422, "fee_too_low"),
        "exceeds block gas limit": (422, "gas_limit_exceeded"),
    }
    for msg, (status, rule) in cases.items():
        wrapped = RuntimeError("send failed")
        wrapped.__cause__ = ValueError(msg)
        err = node_rule_error(wrapped)
        assert err is not None and (domain_status(err), err.rule) == (status, rule), msg
    assert node_rule_error(RuntimeError("connection reset")) is None


def test_model_price_below_minimum_is_422_before_sending(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """Issue 8, finding 4: no free model allocations; no price given pays the minimum."""
    register(client, login, ["user1"], {})
    mmc = service.platform.mmc
    minimum = mmc.call("minModelPrice")
    assert minimum > 1  # the embedded deployment sets the settings' default
    before, block = mmc.call("allocCount"), service.block_number()
    env = task_body()["env"]
    for price in (0, minimum - 1):
        body = {"domain": 0, "env": env, "num_models": 1, "price_wei": price}
        r = client.post(f"{P}/models/requests", json=body, headers=login("user1"))
        assert r.status_code == 422, r.text
        [issue] = r.json()["detail"]
        assert issue["loc"] == ["body", "price_wei"] and issue["type"] == "price_below_minimum"
        assert str(minimum) in issue["msg"]
    assert mmc.call("allocCount") == before and service.block_number() == block  # nothing sent


def test_deadline_too_short_to_accept_and_work_is_422(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """Issue 8, finding 2: a task no offered worker could accept and complete is refused."""
    register(client, login, ["user1"], {})
    shortest, longest = service.platform.tmc.duration_bounds()
    for deadline_s in (shortest - 1, longest + 1):
        r = client.post(f"{P}/tasks", json=task_body(deadline_s=deadline_s), headers=login("user1"))
        assert r.status_code == 422, r.text
        assert r.json()["detail"]["rule"] == "tasks_bad_duration"


SCHEMATHESIS_DEADLINE_S = 60
"""The deadline of the schema-valid ``POST /tasks`` schemathesis sent (the schema's minimum):
it once answered 500 ``OverflowError`` instead of 422 ``tasks_bad_duration``."""


def test_custom_error_web3_cannot_read_as_a_string_is_still_typed(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """web3's eth-tester provider reads every revert as ``Error(string)``. The data of
    ``TasksBadDuration(60, 660, 2592000)`` starts with 60, a valid offset, whose "length" word
    is 660's low bytes << 224 ...: eth_abi raises OverflowError (not DecodingError), which web3
    lets out of the gas estimate. The chain client still raises the typed contract error."""
    register(client, login, ["user1"], {})
    tmc = service.platform.tmc
    shortest, longest = tmc.duration_bounds()
    duration = SCHEMATHESIS_DEADLINE_S
    assert duration < shortest
    args = encode(["uint40", "uint256", "uint256"], [duration, shortest, longest])
    with pytest.raises(OverflowError):  # what web3's provider does with the revert data
        abi.decode(["string"], args)
    reward = tmc.min_reward(duration)
    params = (0, 1, 0, 0, 0, 0, duration, "")
    with pytest.raises(errors.get("TasksBadDuration")) as caught:
        tmc.transact("addTask", params, sender=addr(service, "user1"), value=reward)
    assert caught.value.args_dict == {"duration": duration, "minimum": shortest, "maximum": longest}
    with pytest.raises(errors.get("TasksBadDuration")):
        tmc.estimate("addTask", params, sender=addr(service, "user1"), value=reward)


def test_deadline_schemathesis_sent_is_422_naming_deadline_s(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """The failing request of tests/gateway/test_schemathesis.py (deadline_s 60..63 with a
    valid spec and payment): 422 ``tasks_bad_duration`` naming ``deadline_s`` and the bounds,
    before anything is sent."""
    register(client, login, ["user1"], {})
    tmc = service.platform.tmc
    shortest, longest = tmc.duration_bounds()
    before, block = tmc.call("taskCount"), service.block_number()
    for deadline_s in range(SCHEMATHESIS_DEADLINE_S, SCHEMATHESIS_DEADLINE_S + 4):
        body = task_body(deadline_s=deadline_s, payment_wei=tmc.min_reward(deadline_s))
        r = client.post(f"{P}/tasks", json=body, headers=login("user1"))
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert detail["rule"] == "tasks_bad_duration"
        assert "deadline_s" in detail["msg"] and f"{shortest}" in detail["msg"]
        assert f"{longest}" in detail["msg"]
    assert tmc.call("taskCount") == before and service.block_number() == block  # nothing sent


def test_cancel_open_slots_refunds_them_and_keeps_accepted_ones(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """Issue 8, finding 6: the requester gives up slots nobody holds; the index follows."""
    register(client, login, ["user1"], {"user3": {}})
    r = client.post(f"{P}/tasks", json=task_body(num_workers=3), headers=login("user1"))
    assert r.status_code == 201, r.text
    task_id, offered = r.json()["task_id"], r.json()["offered"]
    assert offered == [addr(service, "user3")]  # one worker for three slots
    service.platform.tmc.transact("acceptOffer", task_id, sender=offered[0])  # the daemon's call
    r = client.post(f"{P}/tasks/{task_id}/cancel-open-slots", headers=login("user3"))
    assert r.status_code == 403, r.text
    r = client.post(f"{P}/tasks/{task_id}/cancel-open-slots", headers=login("user1"))
    assert r.status_code == 200, r.text
    detail = client.get(f"{P}/tasks/{task_id}").json()
    assert detail["num_workers"] == 1 and detail["status"] == "open"
    r = client.post(f"{P}/tasks/{task_id}/cancel-open-slots", headers=login("user1"))
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "tasks_no_open_slot"
