"""All remote ``/rpc`` clients together draw on one gateway-wide gas bucket
(``DRLAAS_RPC_GAS_PER_MINUTE_TOTAL``) besides each one's own, and the chain lock is granted in
arrival order: many clients (or one host with many networks), each within its own budget,
kept the chain lock busy between them, and a platform write waited for as long as reads came.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from backend.api.main import create_app
from backend.services.chain import ChainService, FairRLock
from backend.services.rpc import HEADER_GAS, LIMIT_EXCEEDED, EmbeddedRpc
from backend.services.rpc_budget import GATEWAY, GasBudget, JointBudget
from backend.settings import Settings, SettingsError, load_settings

READ = 16 * HEADER_GAS  # what one eth_feeHistory of 16 headers draws
FEE_HISTORY = {"jsonrpc": "2.0", "id": 1, "method": "eth_feeHistory", "params": ["0x10", "latest"]}


def read(rpc: EmbeddedRpc, client: str) -> dict[str, Any]:
    return rpc.handle(FEE_HISTORY, client)


@pytest.fixture
def rpc(service: ChainService) -> EmbeddedRpc:
    """Each client may read 4 times a minute, all of them together 6 times (frozen clocks)."""
    return EmbeddedRpc(
        service.chain,
        service.lock,
        budget=GasBudget(4 * READ, clock=lambda: 0.0),
        total_budget=GasBudget(6 * READ, clock=lambda: 0.0),
    )


def test_clients_each_within_their_budget_are_bounded_together(rpc: EmbeddedRpc) -> None:
    answers = [read(rpc, f"198.51.100.{i}") for i in range(8)]  # one read each: all in budget
    assert ["result" in a for a in answers] == [True] * 6 + [False] * 2
    refused = answers[-1]["error"]
    assert refused["code"] == LIMIT_EXCEEDED
    assert refused["message"].startswith("gateway-wide execution gas of all remote clients used up")
    assert f"({6 * READ} gas a minute together" in refused["message"]
    assert "retry in " in refused["message"]
    assert "result" in read(rpc, "local")  # this machine's workers and CLI: not metered


def test_the_client_message_still_names_the_clients_own_budget(rpc: EmbeddedRpc) -> None:
    answers = [read(rpc, "198.51.100.1") for _ in range(5)]
    message = answers[-1]["error"]["message"]
    assert message.startswith("execution gas of this client used up")
    assert "gateway-wide" not in message


def test_a_refused_draw_takes_nothing_from_either_bucket(rpc: EmbeddedRpc) -> None:
    for i in range(6):
        assert "result" in read(rpc, f"198.51.100.{i}")
    assert rpc.budget is not None and rpc.total_budget is not None
    assert "error" in read(rpc, "203.0.113.9")  # the gateway's bucket is empty
    assert rpc.budget.available("203.0.113.9") == 4 * READ  # its own bucket was not drawn
    assert rpc.total_budget.available(GATEWAY) == 0


def test_executions_are_charged_to_both_buckets(service: ChainService) -> None:
    mine, total = GasBudget(40_000_000, clock=lambda: 0.0), GasBudget(80_000_000, clock=lambda: 0.0)
    rpc = EmbeddedRpc(service.chain, service.lock, budget=mine, total_budget=total)
    call = {"jsonrpc": "2.0", "id": 1, "method": "eth_estimateGas",
            "params": [{"from": service.chain.accounts[0], "to": service.chain.accounts[1],
                        "value": "0x1"}]}
    assert "result" in rpc.handle(call, "198.51.100.1")
    used = 40_000_000 - mine.available("198.51.100.1")
    assert used >= 21_000 and total.available(GATEWAY) == 80_000_000 - used


def test_an_execution_needs_a_capped_execution_left_in_the_gateways_bucket(
    service: ChainService,
) -> None:
    cap = 1_000_000
    rpc = EmbeddedRpc(
        service.chain, service.lock, gas_cap=cap,
        budget=GasBudget(10 * cap, clock=lambda: 0.0),
        total_budget=GasBudget(10 * cap, clock=lambda: 0.0),
    )
    assert rpc.total_budget is not None
    rpc.total_budget.charge(GATEWAY, 9 * cap + 1)
    call = {"jsonrpc": "2.0", "id": 1, "method": "eth_call",
            "params": [{"to": service.chain.accounts[1]}, "latest"]}
    answer = rpc.handle(call, "198.51.100.1")
    assert answer["error"]["code"] == LIMIT_EXCEEDED
    assert "gateway-wide" in answer["error"]["message"]


def test_the_gateway_applies_the_total_setting(service: ChainService, tmp_path: Path) -> None:
    """``DRLAAS_RPC_GAS_PER_MINUTE_TOTAL`` bounds remote clients that each stay in their own
    budget, whatever network they come from."""
    settings = Settings(
        data_dir=tmp_path, rpc_gas_per_minute=100_000, rpc_gas_per_minute_total=200_000
    )
    app = create_app(settings, chain=service, indexer_interval=None)
    with TestClient(app, client=("198.51.100.1", 4000)) as a:
        assert "result" in a.post("/rpc", json=FEE_HISTORY).json()  # 80,000 of each bucket
        b = TestClient(app, client=("2001:db8:1:2::1", 4000))
        assert "result" in b.post("/rpc", json=FEE_HISTORY).json()
        c = TestClient(app, client=("2001:db8:1:3::1", 4000))
        refused = c.post("/rpc", json=FEE_HISTORY).json()["error"]
        assert refused["code"] == LIMIT_EXCEEDED and "gateway-wide" in refused["message"]
        assert app.state.rpc.total_budget.per_minute == 200_000


def test_the_total_defaults_to_a_multiple_of_the_per_client_budget() -> None:
    assert load_settings().rpc_gas_per_minute_total == 3 * 40_000_000
    assert load_settings(rpc_gas_per_minute=10**8).rpc_gas_per_minute_total == 3 * 10**8


def test_the_total_setting_is_validated_by_name(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DRLAAS_RPC_GAS_PER_MINUTE_TOTAL", "1000000")
    with pytest.raises(SettingsError) as err:
        load_settings()
    message = str(err.value)
    assert "DRLAAS_RPC_GAS_PER_MINUTE_TOTAL (1000000) must be at least" in message
    assert "DRLAAS_RPC_GAS_PER_MINUTE (40000000)" in message
    monkeypatch.setenv("DRLAAS_RPC_GAS_PER_MINUTE_TOTAL", "50000")
    with pytest.raises(SettingsError, match="DRLAAS_RPC_GAS_PER_MINUTE_TOTAL"):
        load_settings()
    monkeypatch.setenv("DRLAAS_RPC_GAS_PER_MINUTE_TOTAL", "90000000")
    assert load_settings().rpc_gas_per_minute_total == 90_000_000


def test_one_budget_cannot_be_both_buckets() -> None:
    budget = GasBudget(1_000_000)
    with pytest.raises(ValueError, match="two budgets"):
        JointBudget(budget, budget)


# -- the chain lock ---------------------------------------------------------------------------


def test_the_chain_lock_is_fair() -> None:
    assert isinstance(ChainService.__dataclass_fields__["lock"].default_factory(), FairRLock)  # type: ignore[misc]


def _wait_until(condition: Any) -> None:
    deadline = time.monotonic() + 10
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.001)


def test_a_waiting_writer_gets_the_lock_before_a_reader_that_asks_again() -> None:
    """A ``/rpc`` batch re-takes the lock between its items, and reads keep coming: the
    thread that waited first gets it at the next release."""
    lock = FairRLock()
    order: list[str] = []
    lock.acquire()  # a batch is running an item

    def write() -> None:
        with lock:
            order.append("write")

    writer = threading.Thread(target=write)
    writer.start()
    _wait_until(lambda: len(lock._waiters) == 1)
    for item in range(50):  # the rest of the batch: release, and at once ask again
        lock.release()
        lock.acquire()
        order.append(f"item {item}")
    lock.release()
    writer.join(10)
    assert order[0] == "write"


def test_the_fair_lock_is_reentrant_and_serves_waiters_in_arrival_order() -> None:
    lock = FairRLock()
    order: list[int] = []
    with lock, lock:  # reentrant
        threads = []

        def take(i: int) -> None:
            with lock:
                order.append(i)

        for i in range(5):
            t = threading.Thread(target=take, args=(i,))
            t.start()
            threads.append(t)
            _wait_until(lambda n=i + 1: len(lock._waiters) == n)  # type: ignore[misc]
    for t in threads:
        t.join(10)
    assert order == [0, 1, 2, 3, 4]
    assert lock._owner is None and not lock._waiters


def test_the_fair_lock_times_out_and_refuses_a_stranger() -> None:
    lock = FairRLock()
    lock.acquire()
    got: list[bool] = []
    t = threading.Thread(target=lambda: got.append(lock.acquire(timeout=0.05)))
    t.start()
    t.join(10)
    assert got == [False] and not lock._waiters  # withdrawn from the queue
    t = threading.Thread(target=lambda: got.append(lock.acquire(blocking=False)))
    t.start()
    t.join(10)
    assert got == [False, False]
    errors: list[BaseException] = []

    def release_foreign() -> None:
        try:
            lock.release()
        except RuntimeError as exc:
            errors.append(exc)

    t = threading.Thread(target=release_foreign)
    t.start()
    t.join(10)
    assert len(errors) == 1 and "does not hold" in str(errors[0])
    lock.release()
    assert lock.acquire(blocking=False)
    lock.release()
