"""The JSON-RPC chain client against a hostile node (audit R2b/R3/R5/R9): its answers are bounded
in bytes and time, its redirects are refused, and the client signs nothing for another chain id
than the pinned one, or above the fee and gas caps."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest
from eth_account import Account

from backend.chain.client import Chain, NodeRefused
from backend.httpbounds import ResponseRefused, ResponseTooLarge, ResponseTooSlow
from backend.settings import SettingsError, load_chain_client_settings

pytestmark = pytest.mark.timeout(60)

TMC = "0x" + "bb" * 20
ANVIL_ID = 31337


class Node:
    """A fake JSON-RPC node: answers from ``self.state``; ``mode`` makes it hostile."""

    def __init__(self) -> None:
        node = self
        self.mode = "ok"
        self.sent = 0
        self.raw: list[str] = []
        self.state: dict[str, Any] = {
            "chain_id": ANVIL_ID, "gas_price": 0, "base_fee": None, "estimate": 50_000,
            "nonce": 0,
        }

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args: Any) -> None:
                pass

            def do_POST(self) -> None:
                body = self.rfile.read(int(self.headers.get("content-length") or 0))
                try:
                    node.answer(self, json.loads(body or b"{}"))
                except (BrokenPipeError, ConnectionResetError):
                    pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def result(self, method: str, params: list[Any]) -> Any:
        s = self.state
        if method == "web3_clientVersion":
            return "hostile/1.0"
        if method == "eth_chainId":
            return hex(s["chain_id"])
        if method == "eth_getBlockByNumber":
            block = {
                "number": "0x10", "hash": "0x" + "11" * 32, "parentHash": "0x" + "22" * 32,
                "timestamp": "0x6000000", "gasLimit": "0x1c9c380", "gasUsed": "0x0",
                "transactions": [], "miner": "0x" + "00" * 20, "difficulty": "0x0",
                "extraData": "0x", "logsBloom": "0x" + "00" * 256, "nonce": "0x" + "00" * 8,
                "sha3Uncles": "0x" + "33" * 32, "stateRoot": "0x" + "44" * 32,
                "receiptsRoot": "0x" + "55" * 32, "transactionsRoot": "0x" + "66" * 32,
                "size": "0x100", "uncles": [], "mixHash": "0x" + "77" * 32,
            }
            if s["base_fee"] is not None:
                block["baseFeePerGas"] = hex(s["base_fee"])
            return block
        if method == "eth_gasPrice":
            return hex(s["gas_price"])
        if method == "eth_getTransactionCount":
            return hex(s["nonce"])
        if method == "eth_estimateGas":
            return hex(s["estimate"])
        if method == "eth_sendRawTransaction":
            self.raw.append(params[0])
            return "0x" + "ab" * 32
        if method == "eth_getTransactionReceipt":
            return {
                "transactionHash": "0x" + "ab" * 32, "blockNumber": "0x11",
                "blockHash": "0x" + "11" * 32, "status": "0x1", "gasUsed": "0x5208",
                "effectiveGasPrice": "0x0", "logs": [], "contractAddress": None,
                "transactionIndex": "0x0", "from": "0x" + "00" * 20, "to": TMC,
                "cumulativeGasUsed": "0x5208", "logsBloom": "0x" + "00" * 256, "type": "0x0",
            }
        return None

    def answer(self, h: Any, doc: Any) -> None:
        if self.mode == "redirect":
            h.send_response(307)
            h.send_header("location", "http://127.0.0.1:9/internal-only")
            h.send_header("content-length", "0")
            h.end_headers()
            return
        if self.mode in ("endless", "drip"):
            h.send_response(200)
            h.send_header("content-type", "application/json")
            h.send_header("transfer-encoding", "chunked")
            h.end_headers()
            t0 = time.monotonic()
            piece = b" " * 65536 if self.mode == "endless" else b" "
            while self.sent < 64 * 2**20 and time.monotonic() - t0 < 10:
                h.wfile.write(b"%x\r\n%s\r\n" % (len(piece), piece))
                self.sent += len(piece)
                if self.mode == "drip":
                    h.wfile.flush()
                    time.sleep(0.2)
            out = json.dumps({"jsonrpc": "2.0", "id": doc.get("id"), "result": "hostile"})
            h.wfile.write(b"%x\r\n%s\r\n0\r\n\r\n" % (len(out), out.encode()))
            return
        if isinstance(doc, list):
            out: Any = [
                {"jsonrpc": "2.0", "id": d["id"], "result": self.result(d["method"], d["params"])}
                for d in doc
            ]
        else:
            out = {"jsonrpc": "2.0", "id": doc["id"],
                   "result": self.result(doc["method"], doc.get("params") or [])}
        data = json.dumps(out).encode()
        h.send_response(200)
        h.send_header("content-type", "application/json")
        h.send_header("content-length", str(len(data)))
        h.end_headers()
        h.wfile.write(data)


@pytest.fixture
def node(monkeypatch: pytest.MonkeyPatch) -> Iterator[Node]:
    for var in ("DRLAAS_CHAIN_ID", "DRLAAS_CONTRACTS", "DRLAAS_TX_MAX_FEE_PER_GAS_WEI",
                "DRLAAS_TX_MAX_GAS", "DRLAAS_CHAIN_MAX_RESPONSE_BYTES", "DRLAAS_CHAIN_TIMEOUT_S"):
        monkeypatch.delenv(var, raising=False)
    n = Node()
    yield n
    n.server.shutdown()
    n.server.server_close()


def _connect(node: Node, **kw: Any) -> tuple[Chain, str]:
    account = Account.create()
    chain = Chain.rpc(node.url, private_keys=["0x" + bytes(account.key).hex()], **kw)
    return chain, account.address


def _accept(chain: Chain, sender: str) -> Any:
    return chain.register("TasksManager", TMC).transact("acceptOffer", 1, sender=sender)


# -- bounded answers (R2b, R3) and redirects (R9) --------------------------------------------------
def test_endless_answer_is_cut_at_the_cap(node: Node) -> None:
    node.mode = "endless"
    limits = load_chain_client_settings(chain_max_response_bytes=2**20)
    t0 = time.monotonic()
    with pytest.raises(ResponseTooLarge, match=f"cap of {2**20} bytes") as ei:
        _connect(node, limits=limits)
    assert time.monotonic() - t0 < 10
    assert node.url in str(ei.value)
    assert node.sent < 2**20 + 16 * 2**20


def test_slow_drip_ends_at_the_deadline(node: Node) -> None:
    node.mode = "drip"
    limits = load_chain_client_settings(chain_timeout_s=0.5)
    t0 = time.monotonic()
    with pytest.raises(ResponseTooSlow, match="deadline of 1 s"):
        _connect(node, limits=limits)
    assert time.monotonic() - t0 < 5  # the drip lasts 10 s


def test_redirects_are_refused(node: Node) -> None:
    node.mode = "redirect"
    with pytest.raises(ResponseRefused, match="redirects .*not followed"):
        _connect(node)


# -- the pinned chain id (R5) ----------------------------------------------------------------------
def test_a_node_on_another_chain_is_refused(node: Node, monkeypatch: pytest.MonkeyPatch) -> None:
    node.state["chain_id"] = 1  # Ethereum mainnet
    _connect(node)  # nothing pins the chain: as before
    monkeypatch.setenv("DRLAAS_CHAIN_ID", str(ANVIL_ID))
    with pytest.raises(NodeRefused, match="reports chain id 1, but DRLAAS_CHAIN_ID pins"):
        _connect(node)
    node.state["chain_id"] = ANVIL_ID
    chain, _ = _connect(node)
    assert chain.chain_id == ANVIL_ID
    # every pin holds: the caller's (a worker's pin on first use) and the operator's
    with pytest.raises(NodeRefused, match="the caller pins chain id 5"):
        _connect(node, chain_id=5)
    node.state["chain_id"] = 5
    with pytest.raises(NodeRefused, match="DRLAAS_CHAIN_ID pins chain id 31337"):
        _connect(node, chain_id=5)  # a caller cannot lift the operator's pin
    monkeypatch.delenv("DRLAAS_CHAIN_ID")
    assert _connect(node, chain_id=5)[0].chain_id == 5


def test_the_deployment_pins_the_chain(
    node: Node, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    contracts = tmp_path / "contracts.json"
    contracts.write_text(json.dumps({"TasksManager": TMC, "chain_id": 2025}))
    monkeypatch.setenv("DRLAAS_CONTRACTS", str(contracts))
    with pytest.raises(NodeRefused, match="DRLAAS_CONTRACTS deployment pins chain id 2025"):
        _connect(node)
    node.state["chain_id"] = 2025
    _connect(node)


# -- fee, gas and nonce caps (R5) ------------------------------------------------------------------
def test_free_gas_chain_signs_as_before(node: Node) -> None:
    node.state["base_fee"] = 0  # the consortium chain and anvil (--block-base-fee-per-gas 0)
    chain, sender = _connect(node)
    receipt = _accept(chain, sender)
    assert receipt.status == 1 and len(node.raw) == 1


def test_legacy_gas_price_above_the_cap_is_refused(node: Node) -> None:
    node.state["gas_price"] = 33_334 * 10**9
    chain, sender = _connect(node)
    with pytest.raises(NodeRefused, match="gas price .* above the cap"):
        _accept(chain, sender)
    assert node.raw == []


def test_base_fee_above_the_cap_is_refused(node: Node) -> None:
    node.state["base_fee"] = 10**15
    chain, sender = _connect(node)
    with pytest.raises(NodeRefused, match="base fee .* above the cap"):
        _accept(chain, sender)
    assert node.raw == []


def test_gas_above_the_cap_is_refused(node: Node) -> None:
    node.state["estimate"] = 50_000_000
    chain, sender = _connect(node)
    with pytest.raises(NodeRefused, match="50000000 gas .* cap of 30000000"):
        _accept(chain, sender)
    assert node.raw == []


def test_the_embedded_chain_asks_fees_under_the_default_cap() -> None:
    chain = Chain.embedded(accounts=1)
    base = chain.w3.eth.get_block("latest")["baseFeePerGas"]
    assert 2 * base <= load_chain_client_settings().tx_max_fee_per_gas_wei


def test_bad_settings_name_their_variable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DRLAAS_TX_MAX_GAS", "10")
    with pytest.raises(SettingsError, match="DRLAAS_TX_MAX_GAS"):
        load_chain_client_settings()
