"""Slow clients and greedy faucet users (audit of 2026-12-03).

Downloads: a streamed response holds no in-flight slot once it starts, so clients that open
downloads and never read cannot answer every other route 503; a client may run at most
``max_downloads_per_client`` downloads at once (429 ``downloads_per_client``), and a download
whose client reads nothing for ``download_idle_timeout_s`` is given up, its connection closed.

Faucet: one client (IP address) gets at most ``faucet_per_client_per_minute`` top-ups a minute
whatever keys it signs in with (429 ``faucet_client_rate``), and one address at most
``faucet_max_per_address`` top-ups ever (429 ``faucet_address_lifetime``, no Retry-After).

``/rpc``: an unexpected exception answers -32603 "internal error", its text only in the log.
"""

from __future__ import annotations

import json
import logging
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from eth_account import Account
from fastapi import FastAPI
from safetensors.numpy import save as save_safetensors

from backend.api.main import create_app
from backend.api.shedding import LoadShedder
from backend.auth import bearer_headers
from backend.services.chain import ChainService
from backend.services.faucet import FAUCET_THRESHOLD_WEI, FAUCET_WEI, Faucet, FaucetLimited
from backend.services.rpc import INTERNAL_ERROR, EmbeddedRpc
from backend.services.specs import validate_env
from backend.settings import Settings
from backend.store.bundle import add_bundle, canonical_json

from .conftest import P, register, serving
from .test_faucet import URL as FAUCET_URL
from .test_faucet import make_client, sign_in, spend
from .test_overload import run_in_fresh_loop

IN_FLIGHT = 2
PER_CLIENT = 2
IDLE_S = 3.0
ENV3 = {"rows": 10, "cols": 10, "agents": 3, "walls": [0, 2]}


# -- downloads ------------------------------------------------------------------------------


@pytest.fixture
def served(tmp_path: Path, service: ChainService) -> Iterator[tuple[str, FastAPI]]:
    """A real uvicorn gateway (a socket can stall only there) with small limits."""
    settings = Settings(
        data_dir=tmp_path / "data",
        max_in_flight=IN_FLIGHT,
        max_downloads_per_client=PER_CLIENT,
        download_idle_timeout_s=IDLE_S,
    )
    app = create_app(settings, chain=service, indexer_interval=0.1)
    with serving(app) as url:
        yield url, app


def _list_big_model(base: str, app: FastAPI, service: ChainService) -> tuple[int, int]:
    """A listed model whose weights (16 MB) are far more than the socket buffers hold."""
    with httpx.Client(base_url=base, timeout=60) as c:
        assert service.demo_keys is not None
        headers = dict(bearer_headers(service.demo_keys.sign_in(c, "user3")))
        register(c, lambda _name: headers, [], {"user3": {"domains": [0]}})  # type: ignore[arg-type]
        weights = save_safetensors({"w": np.ones(4_000_000, np.float32)}, metadata={"name": "big"})
        card = canonical_json(
            {
                "format": "drlaas-model/1",
                "env": validate_env(ENV3).to_dict(),
                "metrics": {"success": 0.9},
                "name": "big",
            }
        )
        cid = add_bundle(app.state.store, {"model.safetensors": weights, "model.json": card})
        r = c.post(
            f"{P}/models",
            json={"cid": cid, "description": "big", "domain": 0, "env": ENV3},
            headers=headers,
        )
        assert r.status_code == 201, r.text
        return int(r.json()["id"]), len(weights)


def _stalled_download(base: str, model_id: int) -> socket.socket:
    """A download request whose client then reads (almost) nothing, on a tiny receive window."""
    host, port = base.removeprefix("http://").split(":")
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.connect((host, int(port)))
    s.sendall(f"GET {P}/models/{model_id}/download HTTP/1.1\r\nHost: x\r\n\r\n".encode())
    s.settimeout(30)
    assert s.recv(12).startswith(b"HTTP/1.1 200"), "the download did not start"
    return s


def _drain(s: socket.socket) -> int:
    """Bytes until the server closes the connection."""
    s.settimeout(30)
    n = 0
    while chunk := s.recv(1 << 16):
        n += len(chunk)
    return n


def test_stalled_downloads_hold_no_slot_are_capped_per_client_and_given_up(
    served: tuple[str, FastAPI], service: ChainService
) -> None:
    base, app = served
    model_id, size = _list_big_model(base, app, service)
    socks = [_stalled_download(base, model_id) for _ in range(PER_CLIENT)]
    try:
        time.sleep(0.5)  # both streams are blocked on their clients' full buffers by now
        with httpx.Client(base_url=base, timeout=10) as c:
            for _ in range(3):  # more requests than max_in_flight: none is shed
                for path in ("/health", "/tasks", "/models"):
                    r = c.get(P + path)
                    assert r.status_code == 200, (path, r.status_code, r.text)
            # the same client's next download is over its cap: 429 naming the limit
            r = c.get(f"{P}/models/{model_id}/download")
            assert r.status_code == 429, r.text
            assert r.json()["detail"]["rule"] == "downloads_per_client"
            assert "max_downloads_per_client" in r.json()["detail"]["msg"]
            assert int(r.headers["Retry-After"]) >= 1
        # nothing read for IDLE_S: each stream is given up and its connection closed, short
        time.sleep(IDLE_S + 1.5)
        for s in socks:
            assert _drain(s) < size
    finally:
        for s in socks:
            s.close()
    with httpx.Client(base_url=base, timeout=60) as c:  # their places are free again
        r = c.get(f"{P}/models/{model_id}/download")
        assert r.status_code == 200 and len(r.content) == size
    # the server frees the slot after its last byte is sent, which the client may see first
    pool, give_up = app.state.download_pool, time.monotonic() + 10
    while (pool.total or pool.by_client) and time.monotonic() < give_up:
        time.sleep(0.05)
    assert pool.total == 0 and not pool.by_client


def test_shedder_frees_the_slot_once_the_response_starts() -> None:
    """The body of a started response waits on the client only: it holds no slot."""
    seen: list[int] = []
    sent: list[dict[str, Any]] = []

    async def inner(scope: dict, receive: object, send: Any) -> None:
        seen.append(shedder.in_flight)  # working on the request: it counts
        await send({"type": "http.response.start", "status": 200, "headers": []})
        seen.append(shedder.in_flight)  # streaming the body: it does not
        await send({"type": "http.response.body", "body": b"x", "more_body": False})

    shedder = LoadShedder(inner, limit=1, retry_after=1)

    async def send(message: dict[str, Any]) -> None:
        sent.append(message)

    async def call() -> None:
        await shedder({"type": "http", "client": ("10.0.0.1", 1)}, None, send)
        await shedder({"type": "http"}, None, send)

    run_in_fresh_loop(call)
    assert seen == [1, 0, 1, 0] and shedder.in_flight == 0 and shedder.shed == 0
    assert [m["type"] for m in sent].count("http.response.start") == 2


# -- faucet ---------------------------------------------------------------------------------


def test_one_client_cannot_take_the_whole_faucet(service: ChainService) -> None:
    now = [1000.0]
    faucet = Faucet(
        service, interval_s=60, per_minute=10, per_client_per_minute=2, clock=lambda: now[0]
    )
    greedy = [Account.create() for _ in range(3)]
    for a in greedy[:2]:
        assert faucet.top_up(a.address, client="10.0.0.1").tx_hash is not None
    with pytest.raises(FaucetLimited) as err:  # a third fresh key from the same client
        faucet.top_up(greedy[2].address, client="10.0.0.1")
    assert (err.value.rule, err.value.retry_after) == ("faucet_client_rate", 60)
    assert service.chain.balance(greedy[2].address) == 0
    newcomer = Account.create()  # another client is still served
    assert faucet.top_up(newcomer.address, client="10.0.0.2").tx_hash is not None
    now[0] += 60  # the client's minute is over
    assert faucet.top_up(greedy[2].address, client="10.0.0.1").tx_hash is not None


def test_per_client_limit_through_the_gateway(tmp_path: Path, service: ChainService) -> None:
    """The route passes no client: the gateway's request context names it (all TestClient
    requests come from one client)."""
    settings = Settings(data_dir=tmp_path / "d", auth_nonces_per_minute=1000)
    limit = Settings.model_fields["faucet_per_client_per_minute"].default
    assert limit < settings.faucet_per_minute  # one client cannot take the overall budget
    people = [Account.create() for _ in range(limit + 1)]
    with make_client(settings, service) as c:
        answers = [c.post(FAUCET_URL, headers=sign_in(c, p)) for p in people]
    assert [a.status_code for a in answers] == [200] * limit + [429]
    assert answers[-1].json()["detail"]["rule"] == "faucet_client_rate"
    assert 1 <= int(answers[-1].headers["Retry-After"]) <= 60
    assert service.chain.balance(people[-1].address) == 0


def test_an_address_gets_a_bounded_number_of_top_ups(service: ChainService) -> None:
    now = [1000.0]
    faucet = Faucet(service, interval_s=30, per_minute=10, max_per_address=3, clock=lambda: now[0])
    me = Account.create()
    for _ in range(3):
        assert faucet.top_up(me.address, client="10.0.0.1").tx_hash is not None
        # moved away again (keeping some for the gas)
        spend(service, me, service.chain.balance(me.address) - FAUCET_THRESHOLD_WEI // 2)
        now[0] += 31
    with pytest.raises(FaucetLimited) as err:
        faucet.top_up(me.address, client="10.0.0.2")
    assert err.value.rule == "faucet_address_lifetime" and err.value.retry_after is None
    assert service.chain.balance(me.address) < FAUCET_THRESHOLD_WEI


def test_lifetime_cap_through_the_gateway(tmp_path: Path, service: ChainService) -> None:
    settings = Settings(data_dir=tmp_path / "d", faucet_interval_s=0)
    cap = Settings.model_fields["faucet_max_per_address"].default
    me = Account.create()
    with make_client(settings, service) as c:
        headers = sign_in(c, me)
        first = c.post(FAUCET_URL, headers=headers)  # an honest user: served as before
        assert first.status_code == 200 and first.json()["tx_hash"]
        spend(service, me, FAUCET_WEI - FAUCET_THRESHOLD_WEI // 2)
        for _ in range(cap - 1):
            assert c.post(FAUCET_URL, headers=headers).status_code == 200
            spend(service, me, FAUCET_WEI)
        r = c.post(FAUCET_URL, headers=headers)
    assert r.status_code == 429
    assert r.json()["detail"]["rule"] == "faucet_address_lifetime"
    assert "Retry-After" not in r.headers  # waiting does not help


# -- /rpc -----------------------------------------------------------------------------------


def test_unexpected_rpc_error_is_generic(
    service: ChainService, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    rpc = EmbeddedRpc(service.chain, service.lock)

    def boom(*_: object, **__: object) -> None:
        raise RuntimeError("secret detail /srv/drlaas/state.db")

    monkeypatch.setattr(rpc, "_dispatch", boom)
    with caplog.at_level(logging.ERROR, logger="backend.services.rpc"):
        answer = rpc.handle({"jsonrpc": "2.0", "id": 7, "method": "eth_blockNumber"})
    assert answer == {
        "jsonrpc": "2.0",
        "id": 7,
        "error": {"code": INTERNAL_ERROR, "message": "internal error"},
    }
    assert "secret" not in json.dumps(answer) and "RuntimeError" not in json.dumps(answer)
    assert "secret detail" in caplog.text  # the details stay on the server
