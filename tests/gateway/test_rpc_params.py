"""``/rpc`` reads parameters the execution-API way (as cast, ethers, viem send them) and names
what is wrong with a bad one (-32602), over real HTTP."""

from __future__ import annotations

from typing import Any

import httpx
import pytest
from eth_account import Account
from eth_utils import keccak

from backend.services.chain import ChainService

IS_REQUESTER = "0x" + keccak(text="isRequester(address)")[:4].hex()


def rpc(gateway: str, method: str, *params: Any) -> dict[str, Any]:
    body = {"jsonrpc": "2.0", "id": 1, "method": method, "params": list(params)}
    # httpx's default 5-s timeout was a timing assert: a loaded CI machine exceeded it once
    r = httpx.post(f"{gateway}/rpc", json=body, timeout=60)
    assert r.status_code == 200, r.text
    return r.json()


def call_of(service: ChainService, **extra: Any) -> dict[str, Any]:
    """``isRequester(admin)`` on the UMC, as cast shapes it (``input`` and ``data``)."""
    data = IS_REQUESTER + "00" * 12 + service.platform.admin[2:].lower()
    return {"to": service.platform.umc.address, "input": data, "data": data, **extra}


def test_call_object_fields(gateway: str, service: ChainService) -> None:
    chain_id = hex(service.chain.chain_id)
    ok = rpc(gateway, "eth_call", call_of(service, chainId=chain_id, nonce="0x5", type="0x2"))
    assert int(ok["result"], 16) == int(
        service.platform.umc.call("isRequester", service.platform.admin)
    )
    only_input = call_of(service)
    del only_input["data"]
    assert rpc(gateway, "eth_call", only_input, "latest")["result"] == ok["result"]

    bad = {
        "input and data differ": call_of(service, data="0x00"),
        "chainId does not match": call_of(service, chainId="0x1"),
        "unknown transaction fields: colour": call_of(service, colour="red"),
        "blob transactions are not served": call_of(
            service, blobVersionedHashes=["0x" + "01" * 32]
        ),
        "transaction type must be one of": call_of(service, type="0x3"),
        "either gasPrice or maxFeePerGas": call_of(service, gasPrice="0x1", maxFeePerGas="0x1"),
        "gas must be a hex quantity": call_of(service, gas="lots"),
    }
    for expected, tx in bad.items():
        err = rpc(gateway, "eth_call", tx, "latest")["error"]
        assert err["code"] == -32602 and expected.split()[0] in err["message"], (expected, err)
    assert "differ" in rpc(gateway, "eth_call", bad["input and data differ"])["error"]["message"]


def test_overrides_are_refused_unless_empty(gateway: str, service: ChainService) -> None:
    assert "result" in rpc(gateway, "eth_call", call_of(service), "latest", {}, None)
    override = {service.platform.umc.address: {"balance": "0x1"}}
    err = rpc(gateway, "eth_call", call_of(service), "latest", override)["error"]
    assert err["code"] == -32602 and "overrides" in err["message"]


def test_unpriced_calls_need_no_balance_priced_ones_do(gateway: str, service: ChainService) -> None:
    empty = Account.create().address
    unpriced = rpc(gateway, "eth_call", call_of(service, **{"from": empty}))
    assert "result" in unpriced
    estimate = rpc(gateway, "eth_estimateGas", {"from": empty, "to": service.chain.accounts[1]})
    assert int(estimate["result"], 16) == 21_000
    priced = rpc(
        gateway, "eth_call", call_of(service, **{"from": empty, "maxFeePerGas": "0x3b9aca00"})
    )
    assert priced["error"]["code"] == -32000 and "insufficient funds" in priced["error"]["message"]


def test_block_parameters(gateway: str, service: ChainService) -> None:
    admin = service.platform.admin
    w3 = service.chain.w3
    genesis = "0x" + bytes(w3.eth.get_block(0)["hash"]).hex()
    at_zero = hex(w3.eth.get_balance(admin, 0))
    assert rpc(gateway, "eth_getBalance", admin, "0x0")["result"] == at_zero
    assert rpc(gateway, "eth_getBalance", admin, {"blockNumber": "0x0"})["result"] == at_zero
    assert (
        rpc(gateway, "eth_getBalance", admin, {"blockHash": genesis, "requireCanonical": True})[
            "result"
        ]
        == at_zero
    )
    assert at_zero != hex(w3.eth.get_balance(admin))  # the deployer has paid gas since
    for bad in (
        {"blockHash": "0x" + "ab" * 32},
        {"blockNumber": "0x0", "blockHash": genesis},
        "next",
    ):
        err = rpc(gateway, "eth_getBalance", admin, bad)["error"]
        assert err["code"] == -32602, (bad, err)
    # "pending" is the latest state here (every transaction is mined at once)
    assert int(rpc(gateway, "eth_estimateGas", call_of(service), "pending")["result"], 16) > 21_000
    assert (
        rpc(gateway, "eth_call", call_of(service), "pending")["result"]
        == (rpc(gateway, "eth_call", call_of(service), "latest")["result"])
    )


def test_log_filters(gateway: str, service: ChainService) -> None:
    keys = service.demo_keys
    assert keys is not None
    with service.lock:
        rc = service.platform.umc.transact("addRequester", sender=keys.address("user4"))
    block_hash = "0x" + bytes(service.chain.w3.eth.get_block(rc.block_number)["hash"]).hex()
    by_hash = rpc(gateway, "eth_getLogs", {"blockHash": block_hash})["result"]
    by_number = rpc(
        gateway, "eth_getLogs", {"fromBlock": hex(rc.block_number), "toBlock": hex(rc.block_number)}
    )["result"]
    assert by_hash == by_number and len(by_hash) == len(rc.events) == 2  # status + added
    assert all(log["transactionHash"] == rc.tx_hash and log["removed"] is False for log in by_hash)
    for bad in (
        {"blockHash": block_hash, "fromBlock": "0x0"},
        {"fromBlock": {"blockNumber": "0x0"}},
        {"since": "0x0"},
    ):
        assert rpc(gateway, "eth_getLogs", bad)["error"]["code"] == -32602, bad


@pytest.mark.parametrize(
    "params",
    [["0x0", "latest"], ["0x401", "latest"], ["0x2", "latest", [75, 25]], ["0x2", "latest", [101]]],
)
def test_fee_history_bounds(gateway: str, params: list[Any]) -> None:
    assert rpc(gateway, "eth_feeHistory", *params)["error"]["code"] == -32602


@pytest.mark.parametrize(
    ("method", "params", "names"),
    [
        ("eth_getTransactionByBlockNumberAndIndex", ["0x1", "latest"], "index"),
        ("eth_getTransactionByBlockNumberAndIndex", ["0x1", "0x"], "index"),
        ("eth_getTransactionByBlockNumberAndIndex", [{}, "0x0"], "block"),
        ("eth_getTransactionByBlockHashAndIndex", ["0x12", "0x0"], "block hash"),
        ("eth_getBlockTransactionCountByNumber", [{}], "block"),
        ("eth_getBlockTransactionCountByHash", [[]], "block hash"),
        ("eth_getTransactionReceipt", ["0x" + "f" * 65], "transaction hash"),
        ("eth_call", [{"to": "0x" + "11" * 20, "accessList": 1}], "accessList"),
        (
            "eth_call",
            [{"to": "0x" + "11" * 20, "authorizationList": {"a": 1}}],
            "authorizationList",
        ),
    ],
)
def test_malformed_parameters_are_named_not_internal_errors(
    gateway: str, method: str, params: list[Any], names: str
) -> None:
    err = rpc(gateway, method, *params)["error"]
    assert err["code"] == -32602 and names in err["message"], err


def test_a_block_past_the_head_is_header_not_found(gateway: str) -> None:
    """State at a block that does not exist (a block itself past the head is null)."""
    for method, params in [
        ("eth_getCode", ["0x" + "11" * 20, "0x" + "f" * 16]),
        ("eth_getBalance", ["0x" + "11" * 20, "0x" + "f" * 16]),
    ]:
        err = rpc(gateway, method, *params)["error"]
        assert (err["code"], err["message"]) == (-32000, "header not found"), (method, err)
