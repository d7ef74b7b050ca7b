"""Foundry's ``cast`` (npm, tests/foundry) against a real gateway's ``/rpc``, unchanged: the
embedded chain speaks the execution JSON-RPC API closely enough for a standard client to call,
estimate, send and read logs, and its answers match the chain itself."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from eth_utils import keccak

from backend.services.chain import ChainService

FOUNDRY = Path(__file__).resolve().parents[1] / "foundry" / "node_modules" / "@foundry-rs"
CAST = next(
    (
        p
        for p in (FOUNDRY / f"cast-linux-{a}" / "bin" / "cast" for a in ("amd64", "arm64"))
        if p.exists()
    ),
    None,
)
pytestmark = pytest.mark.skipif(
    CAST is None,
    reason="Foundry's cast is not installed: run `make setup` (npm ci in tests/foundry)",
)
REQUESTER_ADDED = "0x" + keccak(text="RequesterAdded(address)").hex()
USERS_ALREADY_REGISTERED = "0x" + keccak(text="UsersAlreadyRegistered(address)")[:4].hex()


def cast(url: str, *args: str, ok: bool = True) -> subprocess.CompletedProcess[str]:
    """Run ``cast <args> --rpc-url <url>/rpc``; by default fail the test if cast fails."""
    done = subprocess.run(
        [str(CAST), *args, "--rpc-url", f"{url}/rpc"],
        capture_output=True,
        text=True,
        timeout=120,
        env={"PATH": "/usr/bin:/bin", "HOME": "/nonexistent", "NO_COLOR": "1"},
    )
    if ok:
        assert done.returncode == 0, f"cast {' '.join(args)}: {done.stderr}"
    return done


def out(url: str, *args: str) -> str:
    return cast(url, *args).stdout.strip()


def test_cast_call_reads_views_like_the_chain(gateway: str, service: ChainService) -> None:
    umc, tmc = service.platform.umc.address, service.platform.tmc.address
    keys = service.demo_keys
    assert keys is not None
    admin = service.platform.admin
    # from the zero address, no gas price: unpaid, as on any node
    assert out(gateway, "call", umc, "isAdmin(address)(bool)", admin) == "true"
    assert (
        out(gateway, "call", umc, "isRequester(address)(bool)", admin)
        == str(service.platform.umc.call("isRequester", admin)).lower()
    )
    assert int(out(gateway, "call", tmc, "taskCount()(uint256)").split()[0]) == (
        service.platform.tmc.call("taskCount")
    )


def test_cast_estimate_send_then_call_and_logs(gateway: str, service: ChainService) -> None:
    keys = service.demo_keys
    assert keys is not None
    me = keys.account("user5")
    umc = service.platform.umc
    start = service.block_number()
    assert out(gateway, "call", umc.address, "isRequester(address)(bool)", me.address) == "false"

    estimate = int(out(gateway, "estimate", umc.address, "addRequester()", "--from", me.address))
    # the node's estimate is the least gas that succeeds (to within 1/64; eth-tester's own
    # search stops within 21,000 above it), and cast sends with exactly that
    assert estimate <= umc.estimate("addRequester", sender=me.address)

    receipt = json.loads(
        out(gateway, "send", umc.address, "addRequester()", "--private-key", me.key.hex(), "--json")
    )
    assert receipt["status"] == "0x1" and receipt["from"].lower() == me.address.lower()
    assert estimate - estimate // 64 <= int(receipt["gasUsed"], 16) <= estimate
    assert umc.call("isRequester", me.address) is True  # the chain itself saw it
    assert out(gateway, "call", umc.address, "isRequester(address)(bool)", me.address) == "true"
    # the state before the transaction is still readable at its parent block
    block = int(receipt["blockNumber"], 16)
    before = out(
        gateway,
        "call",
        umc.address,
        "isRequester(address)(bool)",
        me.address,
        "--block",
        str(block - 1),
    )
    assert before == "false"

    logs = json.loads(
        out(
            gateway,
            "logs",
            "--from-block",
            str(start),
            "--address",
            umc.address,
            "RequesterAdded(address indexed)",
            me.address,
            "--json",
        )
    )
    assert len(logs) == 1
    assert logs[0]["transactionHash"] == receipt["transactionHash"]
    assert logs[0]["topics"] == [REQUESTER_ADDED, "0x" + "00" * 12 + me.address[2:].lower()]
    assert logs[0]["removed"] is False

    # a second registration reverts with the contract's custom error, seen by cast
    again = cast(
        gateway, "send", umc.address, "addRequester()", "--private-key", me.key.hex(), ok=False
    )
    assert again.returncode != 0
    assert "execution reverted" in again.stderr and USERS_ALREADY_REGISTERED in again.stderr


def test_cast_reads_receipts_blocks_and_accounts(gateway: str, service: ChainService) -> None:
    keys = service.demo_keys
    assert keys is not None
    me = keys.account("user6")
    umc = service.platform.umc.address
    tx = json.loads(
        out(gateway, "send", umc, "addRequester()", "--private-key", me.key.hex(), "--json")
    )["transactionHash"]

    receipt = json.loads(out(gateway, "receipt", tx, "--json"))
    block = json.loads(out(gateway, "block", receipt["blockNumber"], "--full", "--json"))
    w3 = service.chain.w3
    assert (
        block["hash"]
        == receipt["blockHash"]
        == "0x" + bytes(w3.eth.get_block(int(receipt["blockNumber"], 16))["hash"]).hex()
    )
    assert [t["hash"] for t in block["transactions"]] == [tx]
    assert block["transactions"][0]["input"] == "0x" + keccak(text="addRequester()")[:4].hex()
    assert int(receipt["logsBloom"], 16) != 0 and int(block["logsBloom"], 16) != 0
    assert int(receipt["logsBloom"], 16) & int(block["logsBloom"], 16) == int(
        receipt["logsBloom"], 16
    )

    assert int(out(gateway, "balance", me.address)) == service.chain.balance(me.address)
    nonce = w3.eth.get_transaction_count(me.address)
    assert nonce >= 1
    assert int(out(gateway, "nonce", me.address, "--block", "pending")) == nonce
    assert out(gateway, "code", umc) == "0x" + bytes(w3.eth.get_code(umc)).hex()
    assert int(out(gateway, "chain-id")) == service.chain.chain_id
    assert int(out(gateway, "block-number")) == service.block_number()

    history = json.loads(out(gateway, "rpc", "eth_feeHistory", "0x2", "latest", "[50]"))
    latest = service.block_number()
    assert int(history["oldestBlock"], 16) == latest - 1
    assert len(history["baseFeePerGas"]) == 3 and len(history["reward"]) == 2
    assert int(history["baseFeePerGas"][1], 16) == w3.eth.get_block(latest)["baseFeePerGas"]
