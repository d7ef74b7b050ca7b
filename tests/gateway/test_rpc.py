"""``POST /rpc``: another thread (standing in for a worker daemon or the CLI) uses
``Chain.rpc(<gateway>/rpc)`` to transact against the gateway's embedded chain; the gateway's
indexer thread picks the events up."""

from __future__ import annotations

import functools
import time

import httpx
import pytest

from backend.api.main import create_app
from backend.chain.client import Chain
from backend.chain.errors import ContractError
from backend.chain.platform import TasksManager, UsersManager, cid_commitment
from backend.services.chain import ChainService
from backend.settings import Settings
from backend.store.cid import CID, RAW

# one generous timeout: a loaded CI machine can take seconds to answer, which is not what
# these tests judge (httpx's default is 5 s)
http = functools.partial(httpx.request, timeout=60.0)
REVEAL_CID = str(CID.for_block(b"revealed", RAW))  # a canonical text: the chain refuses others


def test_chain_rpc_through_the_gateway(gateway: str, service: ChainService) -> None:
    keys = service.demo_keys
    assert keys is not None
    requester, worker = keys.account("user8"), keys.account("user9")
    remote = Chain.rpc(f"{gateway}/rpc", private_keys=[requester.key.hex(), worker.key.hex()])
    assert remote.chain_id == service.chain.chain_id
    umc_h = remote.register("UsersManager", service.platform.umc.address)
    tmc_h = remote.register("TasksManager", service.platform.tmc.address)
    umc = UsersManager(remote, umc_h.name, umc_h.contract)
    tmc = TasksManager(remote, tmc_h.name, tmc_h.contract)

    umc.add_requester(requester.address)  # estimateGas + sendRawTransaction + receipt
    umc.add_worker(worker.address, [0], 8, 16, 0)
    with pytest.raises(ContractError) as err:  # revert data crosses the endpoint, typed
        umc.add_requester(requester.address)
    assert err.value.name == "UsersAlreadyRegistered"
    assert err.value.args_dict["account"] == requester.address
    assert umc.call("isRequester", requester.address) is True  # eth_call

    task_id, _ = tmc.add_task(
        requester.address, domain=0, num_workers=1, reward=10**14, duration=86_400
    )
    offered, rc = tmc.allocate(requester.address, task_id)
    assert offered == [worker.address]
    assert [e.name for e in remote.logs(tmc_h, rc.block_number)] == ["TaskOffered", "TaskAllocated"]

    before = remote.now()
    with service.lock:  # chain time moves in process only: /rpc serves no evm_* method
        service.chain.advance_time(700)  # past the 600 s accept window
    assert remote.now() - before > 600  # the remote client sees the new chain time
    with pytest.raises(ContractError) as err:
        tmc.transact("acceptOffer", task_id, sender=worker.address)
    assert err.value.name == "TasksOfferExpired"

    # the gateway's indexer thread saw what the remote client did
    deadline = time.monotonic() + 20
    while True:
        r = http("GET", f"{gateway}/api/tasks/{task_id}")
        if r.status_code == 200 and r.json()["offers"]:
            break
        assert time.monotonic() < deadline, r.text
        time.sleep(0.1)
    assert r.json()["offers"][0]["worker"] == worker.address


def test_commit_then_reveal_through_the_gateway(gateway: str, service: ChainService) -> None:
    """A worker daemon's commit-reveal over ``/rpc``: the chain mines only on transactions and
    serves no ``evm_mine``, so the reveal sent right after its commitment's receipt must be
    estimated in the pending block (the next one), where it is then mined."""
    keys = service.demo_keys
    assert keys is not None
    requester, worker = keys.account("user10"), keys.account("user11")
    remote = Chain.rpc(f"{gateway}/rpc", private_keys=[requester.key.hex(), worker.key.hex()])
    umc_h = remote.register("UsersManager", service.platform.umc.address)
    tmc_h = remote.register("TasksManager", service.platform.tmc.address)
    umc = UsersManager(remote, umc_h.name, umc_h.contract)
    tmc = TasksManager(remote, tmc_h.name, tmc_h.contract)
    umc.add_requester(requester.address)
    umc.add_worker(worker.address, [1], 8, 16, 0)
    task_id, _ = tmc.add_task(
        requester.address, domain=1, num_workers=1, reward=10**14, duration=86_400
    )
    assert tmc.allocate(requester.address, task_id)[0] == [worker.address]
    tmc.transact("acceptOffer", task_id, sender=worker.address)
    commit = tmc.transact("commitCid", cid_commitment(REVEAL_CID, worker.address),
                          sender=worker.address)
    assert remote.w3.eth.block_number == commit.block_number  # nothing mined since
    assert tmc.contract.functions.committedBefore(
        cid_commitment(REVEAL_CID, worker.address)
    ).call(block_identifier="pending") is True  # the next block's view
    reveal = tmc.transact("submitOutcome", task_id, REVEAL_CID, sender=worker.address)
    assert reveal.block_number == commit.block_number + 1
    assert tmc.outcome_of(REVEAL_CID)[0] == worker.address


def test_rpc_refuses_node_signing_and_bad_requests(gateway: str) -> None:
    url = f"{gateway}/rpc"
    r = http("POST",
        url, json={"jsonrpc": "2.0", "id": 1, "method": "eth_sendTransaction", "params": [{}]}
    )
    assert r.json()["error"]["code"] == -32601
    json_type = {"Content-Type": "application/json"}
    assert http("POST", url, content=b"{nope", headers=json_type).json()["error"]["code"] == -32700
    # a body a web page can send across sites without a CORS preflight is refused
    r = http("POST", url, content=b'{"jsonrpc":"2.0","id":1,"method":"eth_chainId"}',
                   headers={"Content-Type": "text/plain"})
    assert r.status_code == 415 and r.json()["detail"]["rule"] == "rpc_content_type", r.text
    batch = [
        {"jsonrpc": "2.0", "id": 1, "method": "eth_chainId", "params": []},
        {"jsonrpc": "2.0", "id": 2, "method": "eth_accounts", "params": []},
        {"jsonrpc": "2.0", "id": 3, "method": "eth_getBalance", "params": ["0x12"]},
    ]
    out = http("POST", url, json=batch).json()
    assert out[0]["result"] == hex(Settings().effective_chain_id or 0)
    assert out[1]["result"] == []  # the node holds nobody's keys
    assert "error" in out[2]
    r = http("POST", url, json={"jsonrpc": "2.0", "id": 4, "method": "eth_chainId", "params": [1]})
    assert r.json()["error"]["code"] == -32602  # eth_chainId takes no params


@pytest.mark.parametrize(
    ("method", "params"),
    [
        ("evm_mine", []),
        ("evm_increaseTime", [3_456_000]),
        ("evm_snapshot", []),
        ("evm_revert", ["0x1"]),
        ("evm_setNextBlockTimestamp", ["0x7fffffff"]),
        ("anvil_setBalance", ["0x" + "11" * 20, "0x1"]),
        ("hardhat_setCode", ["0x" + "11" * 20, "0x00"]),
        ("debug_traceTransaction", ["0x" + "00" * 32]),
        ("admin_nodeInfo", []),
        ("personal_sign", ["0x00", "0x" + "11" * 20]),
        ("eth_sign", ["0x" + "11" * 20, "0x00"]),
        ("eth_sendTransaction", [{}]),
    ],
)
def test_rpc_serves_no_test_or_admin_method(
    gateway: str, service: ChainService, method: str, params: list
) -> None:
    """Anonymous clients reach /rpc: a method that rewrites chain time, state or history (or
    makes the node sign) is "method not found", and the chain is left exactly as it was."""
    head = service.chain.w3.eth.get_block("latest")
    r = http("POST",
        f"{gateway}/rpc", json={"jsonrpc": "2.0", "id": 7, "method": method, "params": params}
    )
    assert r.status_code == 200
    assert r.json() == {
        "jsonrpc": "2.0",
        "id": 7,
        "error": {"code": -32601, "message": f"method {method!r} is not served here"},
    }
    after = service.chain.w3.eth.get_block("latest")
    assert (after["number"], after["hash"], after["timestamp"]) == (
        head["number"],
        head["hash"],
        head["timestamp"],
    )


def test_second_gateway_in_rpc_mode_follows_the_first(
    gateway: str, service: ChainService, tmp_path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """DRLAAS_CHAIN=<gateway>/rpc + DRLAAS_CONTRACTS: a gateway on a "real" node attaches to the
    deployment, indexes it (waiting for 2 confirmations) and does not serve /rpc itself."""
    import json

    from fastapi.testclient import TestClient

    contracts = tmp_path / "contracts.json"
    contracts.write_text(json.dumps(service.addresses()))
    monkeypatch.setenv("DRLAAS_CONTRACTS", str(contracts))
    other = Settings(data_dir=tmp_path / "b", chain=f"{gateway}/rpc", confirmations=2)
    keys = service.demo_keys
    assert keys is not None
    with service.lock:
        service.platform.umc.add_worker(keys.address("user7"), [1], 4, 8, 0)
    with TestClient(create_app(other, indexer_interval=None)) as c:
        app = c.app
        assert app.state.chain.chain.kind == "rpc"  # type: ignore[attr-defined]
        assert app.state.chain_id == service.chain.chain_id  # type: ignore[attr-defined]
        app.state.indexer.poll()  # type: ignore[attr-defined]
        assert c.get("/api/workers").json()["count"] == 0  # not confirmed yet
        with service.lock:
            service.chain._tester.mine_blocks(2)
        app.state.indexer.poll()  # type: ignore[attr-defined]
        listed = c.get("/api/workers", params={"domain": 1}).json()
        assert [w["address"] for w in listed["data"]] == [keys.address("user7")]
        r = c.post("/rpc", json={"jsonrpc": "2.0", "id": 1, "method": "eth_chainId"})
        assert r.status_code == 404 and r.json()["detail"]["rule"] == "rpc_not_embedded"


def test_contracts_endpoint_lets_another_process_attach(
    gateway: str, service: ChainService
) -> None:
    info = http("GET", f"{gateway}/api/chain/contracts").json()
    assert info["rpc"] == "/rpc" and info["chain_id"] == service.chain.chain_id
    # a fresh key (a worker daemon's own key file) is topped up by the dev faucet first:
    # eth-tester refuses even eth_call from an account that could not pay for the gas
    from eth_account import Account

    from backend.auth import DemoKeys, bearer_headers

    me = Account.create()
    own = DemoKeys(Settings())
    own.add("me", me)
    with httpx.Client(base_url=gateway) as c:
        headers = dict(bearer_headers(own.sign_in(c, "me")))
        first = c.post("/api/chain/faucet", headers=headers).json()
        again = c.post("/api/chain/faucet", headers=headers).json()
    assert int(first["balance_wei"]) == 10 * 10**18 and first["tx_hash"]
    assert again["tx_hash"] is None and again["balance_wei"] == first["balance_wei"]
    remote = Chain.rpc(gateway + info["rpc"], private_keys=[me.key.hex()])
    attached = ChainService.attach(remote, info)
    assert attached.platform.tmc.call("taskCount") == service.platform.tmc.call("taskCount")
    assert attached.deploy_block == service.deploy_block
    attached.platform.umc.add_worker(me.address, [2], 4, 8, 0)  # its own signed transaction
    assert service.platform.umc.call("workerId", me.address) > 0
