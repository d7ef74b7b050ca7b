"""Held-out pass (restarts and real services): the gateway's PostgreSQL unreachable for a while
(a TCP proxy in front of the loopback server is cut, then restored). Before the fix a route that
read the database answered 500 ``internal_error``; now 503 ``database_unavailable`` with
Retry-After, and the gateway and its indexer go on once the database is back. Connections the
server terminated (``pg_terminate_backend``) are replaced by the pool's pre-ping."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import text

from backend.api.main import create_app
from backend.db import make_engine
from backend.services.chain import ChainService
from backend.settings import Settings
from tests.gateway.test_indexer import _activity

APP_NAME = "drlaas-heldout-db-down"


class CuttableProxy:
    """Forwards loopback TCP to PostgreSQL until :meth:`cut` (open connections are reset, new
    ones closed at once), again after :meth:`restore`."""

    def __init__(self, port: int = 5432) -> None:
        self.target = port
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.up = True
        self.open: list[socket.socket] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.server.accept()
            except OSError:
                return
            if not self.up:
                client.close()
                continue
            upstream = socket.create_connection(("127.0.0.1", self.target))
            self.open += [client, upstream]
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pipe, args=(a, b), daemon=True).start()

    @staticmethod
    def _pipe(a: socket.socket, b: socket.socket) -> None:
        try:
            while data := a.recv(65536):
                b.sendall(data)
        except OSError:
            pass
        for sock in (a, b):
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def cut(self) -> None:
        self.up = False
        for sock in self.open:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self.open = []

    def restore(self) -> None:
        self.up = True

    def close(self) -> None:
        self.cut()
        self.server.close()


@pytest.fixture
def pg() -> Iterator[str]:
    from tests.backend.conftest import pg_url

    yield from pg_url.__wrapped__()


def test_postgresql_unreachable_is_503_and_the_gateway_goes_on(
    pg: str, service: ChainService, tmp_path: Path
) -> None:
    proxy = CuttableProxy()
    url = pg.replace("127.0.0.1:5432", f"127.0.0.1:{proxy.port}") + f"&application_name={APP_NAME}"
    app = create_app(Settings(data_dir=tmp_path / "data", database=url), chain=service,
                     indexer_interval=None)
    direct = make_engine(pg)
    try:
        with TestClient(app, raise_server_exceptions=False) as client:
            assert client.get("/api/tasks").status_code == 200
            with direct.connect() as c:  # the server drops the gateway's connections
                killed = c.scalar(text("SELECT count(pg_terminate_backend(pid)) FROM "
                                       "pg_stat_activity WHERE application_name = :n"),
                                  {"n": APP_NAME})
            assert killed >= 1
            assert client.get("/api/tasks").status_code == 200  # pre-ping reconnects

            proxy.cut()
            r = client.get("/api/tasks")
            assert r.status_code == 503, r.text
            assert r.json()["detail"]["rule"] == "database_unavailable"
            assert int(r.headers["Retry-After"]) >= 1
            health = client.get("/api/health")
            assert health.status_code == 503 and health.json()["database"] == "unavailable"
            _activity(service, 1)  # events while the database is down

            proxy.restore()
            assert client.get("/api/tasks").status_code == 200
            app.state.indexer.poll()  # what the indexer thread does next
            tasks = client.get("/api/tasks").json()["data"]
            assert [(t["id"], t["offered"]) for t in tasks] == [(1, 2)]
    finally:
        proxy.close()
        direct.dispose()
