"""``/rpc`` is anonymous, and every ``eth_call`` / ``eth_estimateGas`` runs on py-evm under the
chain lock: each execution is capped, an estimate runs a bounded number of executions, and a
client that burns its gas budget waits (-32005) while others go on."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from backend.api.main import create_app
from backend.services.chain import ChainService
from backend.services.rpc import LIMIT_EXCEEDED, SERVER_ERROR, EmbeddedRpc
from backend.services.rpc_budget import GasBudget
from backend.settings import Settings

LOOP = "0x5b600056"  # JUMPDEST PUSH1 0 JUMP: runs until the gas is gone
CAP = 300_000


def burn_then_stop(units: int) -> str:
    """Init code that spends gas in a counted loop, then returns: succeeds with enough gas."""
    n = units.to_bytes(3, "big").hex()
    # PUSH3 n; JUMPDEST(4); PUSH1 1; SWAP1; SUB; DUP1; PUSH1 4; JUMPI; STOP
    return f"0x62{n}5b6001900380600457 00".replace(" ", "")


def call(rpc: EmbeddedRpc, method: str, params: list[Any], client: str = "a") -> dict[str, Any]:
    return rpc.handle({"jsonrpc": "2.0", "id": 1, "method": method, "params": params}, client)


@pytest.fixture
def rpc(service: ChainService) -> EmbeddedRpc:
    now = [0.0]
    budget = GasBudget(4 * CAP, clock=lambda: now[0])
    server = EmbeddedRpc(service.chain, service.lock, gas_cap=CAP, budget=budget)
    server.clock = now  # type: ignore[attr-defined]  # the test moves time
    return server


def test_a_call_without_gas_or_over_the_cap_runs_at_the_cap(rpc: EmbeddedRpc) -> None:
    for tx in ({"data": LOOP}, {"data": LOOP, "gas": hex(45_000_000)}):
        err = call(rpc, "eth_call", [tx, "latest"])["error"]
        # out of gas is a server error naming the allowance, not a revert (code 3)
        assert err["code"] == SERVER_ERROR and f"exceeds allowance ({CAP})" in err["message"]
        rpc.clock[0] += 60  # type: ignore[attr-defined]


def test_an_estimate_is_exact_enough_and_bounded(rpc: EmbeddedRpc) -> None:
    code = burn_then_stop(2_000)
    est = int(call(rpc, "eth_estimateGas", [{"data": code}, "latest"])["result"], 16)
    # the estimate succeeds and its nearest lower limits fail (to within 1/64)
    ok = call(rpc, "eth_call", [{"data": code, "gas": hex(est)}, "latest"])
    assert "result" in ok, ok
    rpc.clock[0] += 60  # type: ignore[attr-defined]
    short = call(rpc, "eth_call", [{"data": code, "gas": hex(est - est // 64 - 1)}, "latest"])
    assert short["error"]["code"] == SERVER_ERROR
    # a call that needs more than the cap: refused, after one capped execution
    rpc.clock[0] += 60  # type: ignore[attr-defined]
    before = rpc.budget.available("a")  # type: ignore[union-attr]
    err = call(rpc, "eth_estimateGas", [{"data": burn_then_stop(20_000)}, "latest"])["error"]
    assert err["code"] == SERVER_ERROR and "exceeds allowance" in err["message"]
    assert before - rpc.budget.available("a") == CAP  # type: ignore[union-attr]


def test_a_client_that_burns_its_budget_waits_and_others_do_not(rpc: EmbeddedRpc) -> None:
    for _ in range(4):  # the budget is four capped executions a minute
        assert call(rpc, "eth_call", [{"data": LOOP}, "latest"])["error"]["code"] == SERVER_ERROR
    err = call(rpc, "eth_call", [{"data": LOOP}, "latest"])["error"]
    assert err["code"] == LIMIT_EXCEEDED and "retry in 15 s" in err["message"]
    # a batch cannot get around it either
    batch = rpc.handle(
        [
            {"jsonrpc": "2.0", "id": i, "method": "eth_call", "params": [{"data": LOOP}]}
            for i in range(3)
        ],
        "a",
    )
    assert [r["error"]["code"] for r in batch] == [LIMIT_EXCEEDED] * 3
    # another client, and the cheap methods of the same client, are served
    assert call(rpc, "eth_call", [{"data": LOOP}, "latest"], "b")["error"]["code"] == SERVER_ERROR
    assert "result" in call(rpc, "eth_blockNumber", [])
    rpc.clock[0] += 15  # type: ignore[attr-defined]  # one capped execution refilled
    assert call(rpc, "eth_call", [{"data": LOOP}, "latest"])["error"]["code"] == SERVER_ERROR
    # the machine's own processes (workers, CLI, indexer of an embedded platform) are capped
    # per execution but not metered
    for _ in range(6):
        err = call(rpc, "eth_call", [{"data": LOOP}, "latest"], "127.0.0.1")["error"]
        assert err["code"] == SERVER_ERROR


def test_a_priced_call_needs_a_sender_that_can_pay(rpc: EmbeddedRpc) -> None:
    poor = "0x" + "11" * 20
    tx = {"from": poor, "data": "0x00", "gasPrice": hex(10**9), "gas": hex(100_000)}
    err = call(rpc, "eth_call", [tx, "latest"])["error"]
    assert err["code"] == SERVER_ERROR and "insufficient funds" in err["message"]
    del tx["gasPrice"]  # unpriced: no balance needed, as on geth
    assert call(rpc, "eth_call", [tx, "latest"])["result"] == "0x"


def test_log_filters_past_the_head_are_clamped(rpc: EmbeddedRpc) -> None:
    head = int(call(rpc, "eth_blockNumber", [])["result"], 16)
    everything = call(rpc, "eth_getLogs", [{"fromBlock": "0x0", "toBlock": hex(head)}])
    far = call(rpc, "eth_getLogs", [{"fromBlock": "0x0", "toBlock": hex(10**18)}])
    assert far["result"] == everything["result"] and far["result"]  # deployment events
    assert call(rpc, "eth_getLogs", [{"fromBlock": hex(head + 5)}])["result"] == []


def test_the_gateway_applies_the_settings(service: ChainService, tmp_path: Any) -> None:
    settings = Settings(data_dir=tmp_path, rpc_gas_cap=200_000, rpc_gas_per_minute=400_000)
    app = create_app(settings, chain=service, indexer_interval=None)
    with TestClient(app) as c:
        body = {"jsonrpc": "2.0", "id": 1, "method": "eth_call", "params": [{"data": LOOP}]}
        codes = [c.post("/rpc", json=body).json()["error"]["code"] for _ in range(3)]
    assert codes == [SERVER_ERROR, SERVER_ERROR, LIMIT_EXCEEDED]


def test_clients_racing_for_the_last_tokens_draw_them_once() -> None:
    """``take`` checks and draws in one step: eight sign-in requests racing for a bucket that
    holds one token get one admission, not one each (the clock yields the thread, as a busy
    gateway would, between the check and the draw)."""
    import threading
    import time

    def slow_clock() -> float:
        time.sleep(0.002)
        return 0.0  # frozen: no refill

    budget = GasBudget(1, clock=slow_clock)
    start = threading.Barrier(8)
    admitted: list[int] = []

    def ask() -> None:
        start.wait()
        if budget.take("198.51.100.7", 1) == 0:
            admitted.append(1)

    threads = [threading.Thread(target=ask) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(admitted) == 1
    assert budget.wait_s("198.51.100.7", 1) > 0
