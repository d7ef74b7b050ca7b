"""Gateway fixtures: one embedded platform per session (deploying costs ~1 s), rolled back to its
deployed state after each test; a fresh data dir, SQLite database and embedded store per test."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import uvicorn
from eth_account import Account
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.api.main import create_app
from backend.auth import DemoKeys, bearer_headers
from backend.services.chain import ChainService
from backend.settings import Settings

P = "/api"


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("filterwarnings", "ignore:.*httpx2")


@pytest.fixture(scope="session")
def chain_service(tmp_path_factory: pytest.TempPathFactory) -> ChainService:
    return ChainService.embedded(Settings(data_dir=tmp_path_factory.mktemp("chain")))


@pytest.fixture
def service(chain_service: ChainService) -> Iterator[ChainService]:
    snap = chain_service.chain.snapshot()
    try:
        yield chain_service
    finally:
        chain_service.chain.revert(snap)


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path / "data")


@pytest.fixture
def offers_seen() -> list[tuple[int, str]]:
    return []


@pytest.fixture
def app(settings: Settings, service: ChainService, offers_seen: list[tuple[int, str]]) -> FastAPI:
    return create_app(
        settings,
        chain=service,
        on_offer=lambda task_id, worker: offers_seen.append((task_id, worker)),
        indexer_interval=None,
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def gateway(settings: Settings, service: ChainService) -> Iterator[str]:
    """A real HTTP gateway (uvicorn in a thread) on the session chain; yields its base URL."""
    with serving(create_app(settings, chain=service, indexer_interval=0.1)) as url:
        yield url


@contextlib.contextmanager
def serving(app: Any, **config: Any) -> Iterator[str]:
    """Serve ``app`` with uvicorn in a thread on a free loopback port; yields its base URL.
    ``config``: more ``uvicorn.Config`` options (``http=`` a protocol class)."""
    port = _free_port()
    server = uvicorn.Server(
        uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", **config)
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline, "gateway did not start"
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(10)


@pytest.fixture
def client(app: FastAPI) -> Iterator[TestClient]:
    with TestClient(app) as c:
        yield c


Login = Callable[[str], dict[str, str]]


@pytest.fixture
def login(client: TestClient, service: ChainService) -> Login:
    """``login("user1")`` -> bearer headers of that demo user (token cached per name)."""
    cache: dict[str, dict[str, str]] = {}

    def _login(name: str) -> dict[str, str]:
        if name not in cache:
            assert service.demo_keys is not None
            cache[name] = dict(bearer_headers(service.demo_keys.sign_in(client, name)))
        return cache[name]

    return _login


def fund(service: ChainService, address: str, wei: int = 10**18) -> None:
    """Send ``wei`` from the deployer to ``address`` (gas for a key the gateway does not hold)."""
    with service.lock:
        admin = service.chain._keys[service.platform.admin]
        w3 = service.chain.w3
        tx = {
            "to": address,
            "value": wei,
            "gas": 21_000,
            "chainId": service.chain.chain_id,
            "nonce": w3.eth.get_transaction_count(admin.address),
            "maxFeePerGas": 2 * w3.eth.get_block("latest")["baseFeePerGas"],
            "maxPriorityFeePerGas": 0,
        }
        w3.eth.send_raw_transaction(admin.sign_transaction(tx).raw_transaction)


def signed_in_outsider(client: TestClient, service: ChainService, settings: Any) -> tuple:
    """(account, headers): a funded key the gateway does not hold (its writes come back to
    sign), signed in."""
    account = Account.create()
    keys = DemoKeys(settings)
    keys.add("outsider", account)
    fund(service, account.address)
    return account, dict(bearer_headers(keys.sign_in(client, "outsider")))


def addr(service: ChainService, name: str) -> str:
    assert service.demo_keys is not None
    return service.demo_keys.address(name)


ENV = {"rows": 8, "cols": 8, "agents": 2, "max_steps": 50}


def task_body(**over: Any) -> dict[str, Any]:
    body: dict[str, Any] = {
        "env": dict(ENV),
        "observation": {"kind": "odmtl", "window": 3},
        "budget": {"steps": 20_000, "minutes": 10},
        "seed": 7,
        "num_workers": 2,
        "payment_wei": 10**15,
        "deadline_s": 3_600,
    }
    body.update(over)
    return body


def register(
    client: TestClient, login: Login, requesters: list[str], workers: dict[str, dict]
) -> None:
    for name in requesters:
        r = client.post(f"{P}/users/requesters", headers=login(name))
        assert r.status_code == 201, r.text
    for name, caps in workers.items():
        body = {"domains": [0], "cpu_cores": 4, "ram_gb": 8, "gpu_series": 0} | caps
        r = client.post(f"{P}/users/workers", json=body, headers=login(name))
        assert r.status_code == 201, r.text
