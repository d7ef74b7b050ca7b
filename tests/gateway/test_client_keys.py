"""One client is one network: every per-client limit counts an IPv6 client by its /64
(``DRLAAS_CLIENT_IPV6_PREFIX``), not by the address it picked in it, and an IPv4-mapped peer
as its IPv4 address. Keyed by address, one IPv6 host was 2^64 clients, each with a full gas
budget, request and store slots, sign-in messages and faucet top-ups."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path
from typing import Any

import pytest
from eth_account import Account
from fastapi.testclient import TestClient

from backend.api.client_key import client_key, network_key
from backend.api.main import create_app
from backend.api.routes.models import _Download
from backend.services.chain import ChainService
from backend.services.rpc import HEADER_GAS, LIMIT_EXCEEDED
from backend.services.rpc_budget import GasBudget
from backend.settings import Settings, SettingsError, load_settings
from backend.store import EmbeddedStore

from .conftest import P
from .test_faucet import URL as FAUCET_URL
from .test_faucet import sign_in

HOST_A = "2001:db8:1:2::a"  # two addresses one host picks in its /64
HOST_A2 = "2001:db8:1:2:ffff:1234:5678:9abc"
NET_A = "2001:db8:1:2::/64"
HOST_B = "2001:db8:1:3::a"  # the next /64: another client
FEE_HISTORY = {"jsonrpc": "2.0", "id": 1, "method": "eth_feeHistory", "params": ["0x10", "latest"]}


@pytest.mark.parametrize(
    ("host", "prefix", "key"),
    [
        ("198.51.100.7", 64, "198.51.100.7"),
        (HOST_A, 64, NET_A),
        (HOST_A2, 64, NET_A),
        ("2001:DB8:1:2::A", 64, NET_A),  # spelled another way: the same network
        (HOST_A, 48, "2001:db8:1::/48"),
        (HOST_A, 128, "2001:db8:1:2::a/128"),
        ("::ffff:198.51.100.7", 64, "198.51.100.7"),  # IPv4 on a dual-stack socket
        ("fe80::1%eth0", 64, "fe80::/64"),
        ("::1", 64, "::1"),  # this machine keeps the name the routes know it by
        ("127.0.0.1", 64, "127.0.0.1"),
        ("testclient", 64, "testclient"),  # not an address: kept as it is
    ],
)
def test_network_key(host: str, prefix: int, key: str) -> None:
    assert network_key(host, prefix) == key


def test_client_key_reads_the_peer_and_the_apps_prefix(tmp_path: Path) -> None:
    app = create_app(Settings(data_dir=tmp_path, client_ipv6_prefix=56), chain=False)
    assert client_key({"client": (HOST_A, 1), "app": app}) == "2001:db8:1::/56"
    assert client_key({"client": (HOST_A, 1)}) == NET_A  # no app: the default /64
    assert client_key({"client": None, "app": app}) == "unknown"


@pytest.mark.parametrize("prefix", [31, 129, -1])
def test_the_prefix_setting_is_validated_by_name(prefix: int) -> None:
    with pytest.raises(SettingsError, match="DRLAAS_CLIENT_IPV6_PREFIX"):
        load_settings(client_ipv6_prefix=prefix)
    assert load_settings(client_ipv6_prefix=48).client_ipv6_prefix == 48


def test_the_prefix_is_read_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DRLAAS_CLIENT_IPV6_PREFIX", "48")
    assert load_settings().client_ipv6_prefix == 48


def _rpc_app(service: ChainService, tmp_path: Path, **settings: Any) -> Any:
    return create_app(Settings(data_dir=tmp_path, **settings), chain=service, indexer_interval=None)


def test_one_ipv6_network_shares_one_rpc_gas_budget(service: ChainService, tmp_path: Path) -> None:
    """A host that used up its gas cannot go on from the next address of its /64, and cannot
    fill the gateway's bucket table with one bucket per address; the next /64 is served."""
    app = _rpc_app(service, tmp_path)
    with TestClient(app, client=(HOST_A, 4000)) as a:
        budget = app.state.rpc.budget = GasBudget(2 * 16 * HEADER_GAS, clock=lambda: 0.0)
        for _ in range(2):
            assert "result" in a.post("/rpc", json=FEE_HISTORY).json()
        assert budget.available(NET_A) == 0
        same_host = TestClient(app, client=(HOST_A2, 4000))
        refused = same_host.post("/rpc", json=FEE_HISTORY).json()
        assert refused["error"]["code"] == LIMIT_EXCEEDED
        assert "of this client used up" in refused["error"]["message"]
        mapped = TestClient(app, client=("::ffff:198.51.100.7", 4000))
        assert "result" in mapped.post("/rpc", json=FEE_HISTORY).json()
        assert budget.available("198.51.100.7") == 16 * HEADER_GAS  # keyed as its IPv4 address
        other = TestClient(app, client=(HOST_B, 4000))
        assert "result" in other.post("/rpc", json=FEE_HISTORY).json()
    assert set(budget._buckets) == {NET_A, "198.51.100.7", "2001:db8:1:3::/64"}


def test_one_ipv6_network_shares_its_rpc_request_slots(
    service: ChainService, tmp_path: Path
) -> None:
    app = _rpc_app(service, tmp_path, rpc_requests_per_client=1)
    body = {"jsonrpc": "2.0", "id": 1, "method": "eth_blockNumber", "params": []}
    with TestClient(app, client=(HOST_A, 4000)) as a:
        slots = app.state.rpc_slots
        assert slots.take(NET_A) is None  # one request of this network is running
        r = TestClient(app, client=(HOST_A2, 4000)).post("/rpc", json=body)
        assert r.status_code == 429 and r.json()["detail"]["rule"] == "rpc_busy_per_client"
        assert TestClient(app, client=(HOST_B, 4000)).post("/rpc", json=body).status_code == 200
        slots.release(NET_A)
        assert a.post("/rpc", json=body).status_code == 200


def test_one_ipv6_network_shares_its_sign_in_messages(tmp_path: Path) -> None:
    app = create_app(Settings(data_dir=tmp_path, auth_nonces_per_minute=2), chain=False)
    body = {"address": Account.create().address}
    with TestClient(app, client=(HOST_A, 4000)) as a:
        codes = [a.post(f"{P}/auth/nonce", json=body).status_code for _ in range(2)]
        assert codes == [200, 200]
        r = TestClient(app, client=(HOST_A2, 4000)).post(f"{P}/auth/nonce", json=body)
        assert r.status_code == 429 and r.json()["detail"]["rule"] == "auth_rate_limited"
        other = TestClient(app, client=(HOST_B, 4000))
        assert other.post(f"{P}/auth/nonce", json=body).status_code == 200


def test_one_ipv6_network_shares_its_store_read_slots(tmp_path: Path) -> None:
    app = create_app(
        Settings(data_dir=tmp_path, max_store_reads=10, max_store_reads_per_client=1), chain=False
    )
    with TestClient(app, client=(HOST_A, 4000)):
        cid = EmbeddedStore(tmp_path / "ipfs").add(b"a block")
        app.state.store = EmbeddedStore(tmp_path / "ipfs")
        reads = app.state.store_reads
        assert reads.take(NET_A) is None  # one slow read of this network is running
        r = TestClient(app, client=(HOST_A2, 4000)).get(f"{P}/blocks/{cid}")
        assert r.status_code == 429 and r.json()["detail"]["rule"] == "store_reads_per_client"
        assert TestClient(app, client=(HOST_B, 4000)).get(f"{P}/blocks/{cid}").status_code == 200
        reads.release(NET_A)


def test_one_ipv6_network_shares_its_download_slots(tmp_path: Path) -> None:
    app = create_app(
        Settings(data_dir=tmp_path, max_downloads_per_client=1), chain=False
    )
    pool = app.state.download_pool
    assert pool.take(NET_A) is None  # one stalled download of this network

    def download(host: str) -> int:
        sent: list[dict[str, Any]] = []

        async def send(message: dict[str, Any]) -> None:
            sent.append(message)

        async def receive() -> dict[str, Any]:
            return {"type": "http.disconnect"}

        response = _Download(iter([b"weights"]), settings=app.state.settings, what="a model")
        scope = {"type": "http", "client": (host, 4000), "app": app, "method": "GET"}
        # a thread of its own: an event loop another test left running in this one would
        # refuse asyncio.run
        runner = threading.Thread(target=asyncio.run, args=(response(scope, receive, send),))
        runner.start()
        runner.join(30)
        return int(sent[0]["status"])

    assert download(HOST_A2) == 429
    assert download(HOST_B) == 200
    assert pool.by_client == {NET_A: 1}  # given back after the other network's download


def test_one_ipv6_network_shares_its_faucet_top_ups(tmp_path: Path, service: ChainService) -> None:
    """Fresh keys cost nothing, nor do fresh addresses of one's /64."""
    settings = Settings(
        data_dir=tmp_path, faucet_per_client_per_minute=1, auth_nonces_per_minute=1000
    )
    app = create_app(settings, chain=service, indexer_interval=None)
    with TestClient(app, client=(HOST_A, 4000)) as a:
        assert a.post(FAUCET_URL, headers=sign_in(a, Account.create())).status_code == 200
        same_host = TestClient(app, client=(HOST_A2, 4000))
        r = same_host.post(FAUCET_URL, headers=sign_in(same_host, Account.create()))
        assert r.status_code == 429 and r.json()["detail"]["rule"] == "faucet_client_rate"
        other = TestClient(app, client=(HOST_B, 4000))
        assert other.post(FAUCET_URL, headers=sign_in(other, Account.create())).status_code == 200
