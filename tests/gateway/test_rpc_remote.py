"""What a remote ``/rpc`` client can make the embedded chain do while it holds the chain lock:
mine only platform calls and plain transfers within the gas cap and its budget, read logs over
a bounded span, fee rewards over fewer blocks; and a transaction is found by hash from py-evm's
index, not by walking the chain back from the head."""

from __future__ import annotations

from typing import Any

import pytest
from eth_account import Account
from fastapi.testclient import TestClient

from backend.api.main import create_app
from backend.api.routes.rpc import CROSS_SITE
from backend.chain.tx_lookup import indexed_transaction_by_hash
from backend.services.chain import ChainService
from backend.services.rpc import (
    HEADER_GAS,
    INVALID_PARAMS,
    LIMIT_EXCEEDED,
    LOG_BLOCK_GAS,
    MAX_LOG_BLOCKS,
    SERVER_ERROR,
    EmbeddedRpc,
)
from backend.services.rpc_budget import GasBudget
from backend.settings import Settings

LOOP_RUNTIME = "5b600056"  # JUMPDEST PUSH1 0 JUMP: runs until the gas is gone
# init code: CODECOPY the 4 runtime bytes after these 11 to memory 0 and RETURN them
DEPLOY_LOOP = "0x600480600b6000396000f3" + LOOP_RUNTIME
CAP = 3_000_000


def call(rpc: EmbeddedRpc, method: str, params: list[Any], client: str) -> dict[str, Any]:
    return rpc.handle({"jsonrpc": "2.0", "id": 1, "method": method, "params": params}, client)


@pytest.fixture
def rpc(service: ChainService) -> EmbeddedRpc:
    targets = frozenset(h.address for h in service.platform.contracts)
    budget = GasBudget(4 * CAP, clock=lambda: 0.0)
    return EmbeddedRpc(service.chain, service.lock, gas_cap=CAP, budget=budget, targets=targets)


def signed(service: ChainService, sender: str, **tx: Any) -> str:
    w3 = service.chain.w3
    full = {
        "chainId": service.chain.chain_id,
        "nonce": w3.eth.get_transaction_count(sender),
        "maxFeePerGas": 10 * w3.eth.get_block("latest")["baseFeePerGas"],
        "maxPriorityFeePerGas": 0,
        "value": 0,
        **tx,
    }
    return "0x" + bytes(service.chain._keys[sender].sign_transaction(full).raw_transaction).hex()


def test_a_remote_client_cannot_deploy_or_run_its_own_code(
    service: ChainService, rpc: EmbeddedRpc
) -> None:
    me = service.chain.accounts[3]
    create = signed(service, me, data=DEPLOY_LOOP, gas=100_000)
    err = call(rpc, "eth_sendRawTransaction", [create], "198.51.100.7")["error"]
    assert err["code"] == SERVER_ERROR and "contract creation" in err["message"]
    # this machine may (the platform's own tools); then a remote call of that code is refused
    assert "result" in call(rpc, "eth_sendRawTransaction", [create], "local")
    loop = service.chain.w3.eth.get_transaction_receipt(
        service.chain.w3.eth.get_block("latest")["transactions"][0]
    )["contractAddress"]
    assert service.chain.w3.eth.get_code(loop).hex().endswith(LOOP_RUNTIME)
    run = signed(service, me, to=loop, gas=CAP)
    err = call(rpc, "eth_sendRawTransaction", [run], "198.51.100.7")["error"]
    assert err["code"] == SERVER_ERROR and "platform contracts" in err["message"]
    # even with no data: value sent to code runs it
    err = call(
        rpc,
        "eth_sendRawTransaction",
        [signed(service, me, to=loop, gas=CAP, value=1)],
        "198.51.100.7",
    )["error"]
    assert err["code"] == SERVER_ERROR


def test_a_remote_client_may_transfer_and_call_the_platform_within_cap_and_budget(
    service: ChainService, rpc: EmbeddedRpc
) -> None:
    me, you = service.chain.accounts[3], Account.create().address
    ok = call(
        rpc,
        "eth_sendRawTransaction",
        [signed(service, me, to=you, value=5, gas=21_000)],
        "198.51.100.7",
    )
    assert "result" in ok and service.chain.balance(you) == 5
    umc = service.platform.umc
    data = umc.contract.encode_abi("addRequester", [])
    over = signed(service, me, to=umc.address, data=data, gas=CAP + 1)
    err = call(rpc, "eth_sendRawTransaction", [over], "198.51.100.7")["error"]
    assert err["code"] == SERVER_ERROR and str(CAP) in err["message"]
    assert rpc.budget is not None
    before = rpc.budget.available("198.51.100.7")
    tx = signed(service, me, to=umc.address, data=data, gas=CAP)
    assert "result" in call(rpc, "eth_sendRawTransaction", [tx], "198.51.100.7")
    assert umc.call("isRequester", me) is True
    assert rpc.budget.available("198.51.100.7") == before - CAP  # its gas limit, drawn
    # the budget is four capped transactions: the fifth waits
    for _ in range(3):
        rpc.budget.charge("198.51.100.7", CAP)
    left = rpc.budget.available("198.51.100.7")
    again = signed(service, me, to=you, value=1, gas=21_000)
    err = call(rpc, "eth_sendRawTransaction", [again], "198.51.100.7")["error"]
    assert err["code"] == LIMIT_EXCEEDED
    # refused: not mined, and nothing drawn for it
    assert service.chain.balance(you) == 5 and rpc.budget.available("198.51.100.7") == left


def test_remote_log_queries_span_a_bounded_number_of_blocks(service: ChainService) -> None:
    targets = frozenset(h.address for h in service.platform.contracts)
    rpc = EmbeddedRpc(service.chain, service.lock, gas_cap=CAP, budget=None, targets=targets)
    service.chain._tester.mine_blocks(MAX_LOG_BLOCKS + 5)
    whole = {"fromBlock": "earliest", "toBlock": "latest"}
    err = call(rpc, "eth_getLogs", [whole], "198.51.100.7")["error"]
    assert err["code"] == LIMIT_EXCEEDED and str(MAX_LOG_BLOCKS) in err["message"]
    assert call(rpc, "eth_getLogs", [whole], "local")["result"]  # the deployment's events
    head = service.chain.w3.eth.block_number
    recent = {"fromBlock": hex(head - MAX_LOG_BLOCKS + 1)}
    assert call(rpc, "eth_getLogs", [recent], "198.51.100.7")["result"] == []
    # a batch is one request: its calls share the span (50 calls of 500 blocks: one answered)
    half = {"fromBlock": hex(head - MAX_LOG_BLOCKS // 2 + 1)}
    batch = [{"jsonrpc": "2.0", "id": i, "method": "eth_getLogs", "params": [f]}
             for i, f in enumerate([half, half, half, recent])]
    out = rpc.handle(batch, "198.51.100.7")
    assert [("result" in r) for r in out] == [True, True, False, False]
    assert out[2]["error"]["code"] == LIMIT_EXCEEDED and "0 left" in out[2]["error"]["message"]
    assert all("result" in r for r in rpc.handle(batch, "local"))  # the gateway's own reads


def test_block_reads_draw_on_the_remote_clients_gas_budget(
    service: ChainService, rpc: EmbeddedRpc
) -> None:
    """Logs and fee history are read under the chain lock like executions run: a remote
    client pays for them from the same bucket (the audit held the lock 68 s with one batch of
    fee-history reads, 37 s with four parallel log reads, none of it metered)."""
    service.chain._tester.mine_blocks(MAX_LOG_BLOCKS + 5)
    assert rpc.budget is not None
    client = "198.51.100.9"
    full = rpc.budget.available(client)
    assert "result" in call(rpc, "eth_feeHistory", ["0x400", "latest"], client)
    assert rpc.budget.available(client) == full - 1024 * HEADER_GAS
    head = service.chain.w3.eth.block_number
    span = 100
    flt = {"fromBlock": hex(head - span + 1), "toBlock": hex(head)}
    assert "result" in call(rpc, "eth_getLogs", [flt], client)
    assert rpc.budget.available(client) == full - 1024 * HEADER_GAS - span * LOG_BLOCK_GAS
    # the bucket (4 x CAP, frozen clock) runs dry: refused before reading, with the wait
    batch = [{"jsonrpc": "2.0", "id": i, "method": "eth_feeHistory",
              "params": ["0x80", "latest", [50]]} for i in range(4)]
    out = rpc.handle(batch, client)
    refused = [r["error"] for r in out if "error" in r]
    assert refused and all(e["code"] == LIMIT_EXCEEDED and "retry in" in e["message"]
                           for e in refused)
    assert rpc.budget.available(client) >= 0
    # this machine's own clients are not metered; another remote client has its own bucket
    assert "result" in call(rpc, "eth_feeHistory", ["0x400", "latest"], "local")
    assert "result" in call(rpc, "eth_feeHistory", ["0x400", "latest"], "198.51.100.10")


def test_fee_rewards_are_read_over_at_most_128_blocks(rpc: EmbeddedRpc) -> None:
    err = call(rpc, "eth_feeHistory", ["0x81", "latest", [50]], "local")["error"]
    assert err["code"] == INVALID_PARAMS and "128" in err["message"]
    assert "result" in call(rpc, "eth_feeHistory", ["0x80", "latest", [50]], "local")
    assert "result" in call(rpc, "eth_feeHistory", ["0x400", "latest"], "local")  # no rewards


def test_an_old_transaction_is_found_without_walking_the_chain(
    service: ChainService, monkeypatch: pytest.MonkeyPatch
) -> None:
    w3, tester = service.chain.w3, service.chain._tester
    me = service.chain.accounts[3]
    old = w3.eth.send_raw_transaction(signed(service, me, to=me, gas=21_000))
    tester.mine_blocks(50)
    chain = tester.backend.chain
    reads: list[int] = []
    by_number = chain.get_canonical_block_by_number
    monkeypatch.setattr(
        chain, "get_canonical_block_by_number", lambda n: reads.append(n) or by_number(n)
    )
    block, tx, index = indexed_transaction_by_hash(chain, bytes(old))
    assert tx.hash == bytes(old) and index == 0 and len(reads) == 1
    receipt = w3.eth.get_transaction_receipt(old)  # eth-tester's own path uses it too
    assert receipt["blockNumber"] == block.number and len(reads) == 2
    with pytest.raises(Exception, match="No transaction found"):
        tester.get_transaction_receipt("0x" + "11" * 32)


def test_the_gateway_gives_the_rpc_its_platform_targets(
    service: ChainService, tmp_path: Any
) -> None:
    app = create_app(Settings(data_dir=tmp_path), chain=service, indexer_interval=None)
    with TestClient(app) as c:
        assert c.app.state.rpc.targets == {h.address for h in service.platform.contracts}


def test_a_web_page_in_a_browser_here_is_metered(service: ChainService, tmp_path: Any) -> None:
    """This machine's workers and CLI are not metered; a web page that a browser here runs
    (another site's Origin, or DNS rebinding: another Host) is, though it comes from loopback."""
    app = create_app(Settings(data_dir=tmp_path), chain=service, indexer_interval=None)
    body = {"jsonrpc": "2.0", "id": 1, "method": "eth_feeHistory", "params": ["0x10", "latest"]}
    local = {"client": ("127.0.0.1", 50000), "base_url": "http://127.0.0.1:8000"}
    with TestClient(app, **local) as c:
        budget = c.app.state.rpc.budget = GasBudget(4 * CAP, clock=lambda: 0.0)
        full = budget.available(CROSS_SITE)
        assert "result" in c.post("/rpc", json=body).json()
        assert budget.available(CROSS_SITE) == full and budget.available("127.0.0.1") == full
        for headers in ({"Origin": "https://attacker.example"}, {"Host": "attacker.example"}):
            before = budget.available(CROSS_SITE)
            assert "result" in c.post("/rpc", json=body, headers=headers).json()
            assert budget.available(CROSS_SITE) == before - 16 * HEADER_GAS


def test_a_remote_client_runs_a_bounded_number_of_requests_at_once(
    service: ChainService, tmp_path: Any
) -> None:
    """Each request may hold the chain lock (a batch up to 50 times): four parallel log reads
    of one client delayed everyone's by 37 s in the audit. Beyond the bound: 429 at once."""
    settings = Settings(data_dir=tmp_path, rpc_requests_per_client=2)
    app = create_app(settings, chain=service, indexer_interval=None)
    body = {"jsonrpc": "2.0", "id": 1, "method": "eth_blockNumber", "params": []}
    with TestClient(app, client=("198.51.100.7", 4000)) as c:
        slots = c.app.state.rpc_slots
        assert c.post("/rpc", json=body).status_code == 200
        assert slots.by_client == {}  # given back after the answer
        for _ in range(2):  # two requests of this client still running
            assert slots.take("198.51.100.7") is None
        r = c.post("/rpc", json=body)
        assert r.status_code == 429 and r.json()["detail"]["rule"] == "rpc_busy_per_client"
        assert r.headers["Retry-After"] == "1"
        slots.release("198.51.100.7")
        assert c.post("/rpc", json=body).json()["result"].startswith("0x")
    local = {"client": ("127.0.0.1", 4000), "base_url": "http://127.0.0.1:8000"}
    with TestClient(app, **local) as c:  # this machine's workers and CLI: not bounded
        for _ in range(3):
            assert c.app.state.rpc_slots.take("127.0.0.1") in (None, "client")
        assert c.post("/rpc", json=body).status_code == 200


def test_a_set_code_transaction_is_refused_by_its_type(
    service: ChainService, rpc: EmbeddedRpc
) -> None:
    """An EIP-7702 transaction (type 0x04) is a plain transfer by its target, but its
    authorization list gives the signing accounts code (a delegation to a contract on chain):
    what "only platform contracts or plain transfers" means to forbid. It is refused by its
    type, naming it; before, it passed every check of the target."""
    me, you = service.chain.accounts[3], Account.create().address
    key = service.chain._keys[me]
    auth = key.sign_authorization({
        "chainId": service.chain.chain_id,
        "address": service.platform.umc.address,
        "nonce": service.chain.w3.eth.get_transaction_count(me) + 1,
    })
    w3 = service.chain.w3
    tx = key.sign_transaction({
        "type": 4, "chainId": service.chain.chain_id, "nonce": w3.eth.get_transaction_count(me),
        "to": you, "value": 1, "data": b"", "gas": 100_000,
        "maxFeePerGas": 10 * w3.eth.get_block("latest")["baseFeePerGas"],
        "maxPriorityFeePerGas": 0, "authorizationList": [auth],
    })
    raw = "0x" + bytes(tx.raw_transaction).hex()
    err = call(rpc, "eth_sendRawTransaction", [raw], "198.51.100.7")["error"]
    assert err["code"] == SERVER_ERROR and "type 0x04" in err["message"], err
    assert service.chain.balance(you) == 0 and w3.eth.get_code(me) in (b"", "0x")
