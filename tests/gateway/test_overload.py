"""Overload answers 503 + Retry-After naming the rule, never 500: requests beyond the in-flight
limit are shed at once, and a request that finds every pooled database connection busy gets
``database_busy``. Both are behaviour tests (who gets what), with no timing asserted."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path

import httpx
from fastapi import FastAPI
from fastapi.testclient import TestClient

from backend.api.main import create_app
from backend.api.shedding import LoadShedder
from backend.settings import Settings
from backend.store import StoreUnavailable

from .conftest import P


def run_in_fresh_loop(coro_fn) -> None:
    """asyncio.run in a thread of its own: the browser tests' Playwright keeps an event loop
    running in the main thread, where asyncio.run refuses to start."""
    errors: list[BaseException] = []

    def target() -> None:
        try:
            asyncio.run(coro_fn())
        except BaseException as exc:  # noqa: BLE001 - re-raised in the test's thread
            errors.append(exc)

    t = threading.Thread(target=target)
    t.start()
    t.join(timeout=120)
    assert not t.is_alive(), "the async scenario did not finish"
    if errors:
        raise errors[0]


def test_requests_beyond_the_limit_are_shed_then_served_again(tmp_path: Path) -> None:
    app = create_app(
        Settings(data_dir=tmp_path, max_in_flight=2, retry_after_s=3),
        chain=False,
        indexer_interval=None,
    )
    release = asyncio.Event()
    entered = asyncio.Semaphore(0)

    async def slow() -> dict[str, bool]:
        entered.release()
        await release.wait()
        return {"done": True}

    app.add_api_route(f"{P}/test-slow", slow)

    async def scenario() -> None:
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://gw") as client:
            held = [asyncio.create_task(client.get(f"{P}/test-slow")) for _ in range(2)]
            for _ in held:
                await entered.acquire()  # both requests are inside the app
            shed = await client.get(f"{P}/health")
            assert shed.status_code == 503
            assert shed.headers["retry-after"] == "3"
            assert shed.json()["detail"]["rule"] == "overloaded"
            release.set()
            assert [(await t).status_code for t in held] == [200, 200]
            assert (await client.get(f"{P}/test-slow")).status_code == 200  # room again

    run_in_fresh_loop(scenario)


def test_shedder_counts_until_the_response_is_sent() -> None:
    """The in-flight count drops only when the inner app returns, also after an error."""
    seen: list[int] = []

    async def inner(scope: dict, receive: object, send: object) -> None:
        seen.append(shedder.in_flight)
        raise RuntimeError("boom")

    shedder = LoadShedder(inner, limit=1, retry_after=1)

    async def call() -> None:
        try:
            await shedder({"type": "http"}, None, None)
        except RuntimeError:
            pass

    run_in_fresh_loop(call)
    run_in_fresh_loop(call)
    assert seen == [1, 1] and shedder.in_flight == 0 and shedder.shed == 0


def test_exhausted_database_pool_is_503_database_busy(tmp_path: Path) -> None:
    settings = Settings(
        data_dir=tmp_path, db_pool_size=1, db_max_overflow=0, db_pool_timeout_s=0.05
    )
    app: FastAPI = create_app(settings, chain=False, indexer_interval=None)
    with TestClient(app) as client:
        assert client.get(f"{P}/models").status_code == 200
        held = app.state.engine.connect()  # the pool's only connection
        try:
            for path in ("/models", "/tasks"):
                r = client.get(f"{P}{path}")
                assert r.status_code == 503, r.text
                assert r.json()["detail"]["rule"] == "database_busy"
                assert int(r.headers["retry-after"]) >= 1
        finally:
            held.close()
        assert client.get(f"{P}/models").status_code == 200


class _SlowStore:
    """The gateway's store, with reads of blocks that wait for ``release`` (a kubo node
    looking for content nobody holds waits its find timeout, 10 s) or fail as a node that is
    down does (``down``)."""

    def __init__(self, store: object) -> None:
        self.store = store
        self.release = threading.Event()
        self.down = False

    def get_block(self, cid: str, *, max_bytes: int) -> bytes:
        if self.down:
            raise StoreUnavailable("http://kubo:5001", "connection refused", retry_after=7)
        assert self.release.wait(60), "the test never released the store"
        return self.store.get_block(cid, max_bytes=max_bytes)  # type: ignore[attr-defined]

    def close(self) -> None:
        pass


def test_slow_store_reads_are_bounded_per_client_and_overall(tmp_path: Path) -> None:
    """Requests waiting on the store hold a slot each: a client past its share gets 429
    ``store_reads_per_client``, everyone past the total 503 ``store_reads_busy``, at once and
    with Retry-After, while routes that do not read the store still answer. Slots come back
    when the reads finish."""
    from backend.store import EmbeddedStore

    app = create_app(
        Settings(data_dir=tmp_path, max_store_reads=3, max_store_reads_per_client=2,
                 retry_after_s=2),
        chain=False,
        indexer_interval=None,
    )
    real = EmbeddedStore(tmp_path / "ipfs")
    cid = real.add(b"a block")
    slow = app.state.store = _SlowStore(real)
    reads = app.state.store_reads

    async def scenario() -> None:
        def client(ip: str) -> httpx.AsyncClient:
            transport = httpx.ASGITransport(app=app, client=(ip, 4000))
            return httpx.AsyncClient(transport=transport, base_url="http://gw")

        async def until(total: int) -> None:
            for _ in range(2000):
                if reads.total == total:
                    return
                await asyncio.sleep(0.005)
            raise AssertionError(f"{reads.total} store reads in flight, expected {total}")

        async with client("10.0.0.1") as a, client("10.0.0.2") as b, client("10.0.0.3") as c:
            held = [asyncio.create_task(a.get(f"{P}/blocks/{cid}")) for _ in range(2)]
            await until(2)
            mine = await a.get(f"{P}/blocks/{cid}")
            assert mine.status_code == 429, mine.text
            assert mine.json()["detail"]["rule"] == "store_reads_per_client"
            assert mine.headers["retry-after"] == "2"
            held.append(asyncio.create_task(b.get(f"{P}/blocks/{cid}")))
            await until(3)
            full = await c.get(f"{P}/blocks/{cid}")
            assert full.status_code == 503 and full.headers["retry-after"] == "2"
            assert full.json()["detail"]["rule"] == "store_reads_busy"
            assert (await c.get(f"{P}/health")).status_code == 200  # no store: not held up
            slow.release.set()
            done = [await t for t in held]
            assert [r.status_code for r in done] == [200, 200, 200]
            assert done[0].content == b"a block"
            assert reads.total == 0 and reads.by_client == {}
            assert (await c.get(f"{P}/blocks/{cid}")).status_code == 200
            slow.down = True  # a node that is down: 503 naming the store, not a 500
            down = await c.get(f"{P}/blocks/{cid}")
            assert down.status_code == 503 and down.headers["retry-after"] == "7"
            assert down.json()["detail"]["rule"] == "store_unavailable"
            assert reads.total == 0  # the failed read gave its slot back

    run_in_fresh_loop(scenario)
