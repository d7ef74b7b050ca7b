"""Fixtures for the gateway foundation: per-test data dir and database, a movable clock, demo
keys, and a throwaway PostgreSQL schema when PostgreSQL runs on loopback."""

from __future__ import annotations

import datetime as dt
import socket
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from backend.auth import DemoKeys
from backend.settings import Settings


def pytest_configure(config: pytest.Config) -> None:
    # starlette's TestClient still works over httpx; its deprecation notice is not ours to fix.
    config.addinivalue_line("filterwarnings", "ignore:.*httpx2")
    # kombu's SQL transport uses a loader SQLAlchemy 2.1 deprecates; kombu's to change.
    config.addinivalue_line("filterwarnings", "ignore:The ``noload`` loader strategy")


PG_HOST, PG_PORT = "127.0.0.1", 5432


def port_open(host: str, port: int, timeout: float = 0.5) -> bool:
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


class Clock:
    """A clock the test moves: the app reads ``clock()`` for sign-in expiry."""

    def __init__(self) -> None:
        self.now = dt.datetime.now(dt.UTC)

    def __call__(self) -> dt.datetime:
        return self.now

    def advance(self, seconds: float) -> None:
        self.now += dt.timedelta(seconds=seconds)


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path / "data")


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def keys(settings: Settings) -> DemoKeys:
    k = DemoKeys(settings)
    k.create("alice")
    k.create("bob")
    return k


@pytest.fixture
def pg_url() -> Iterator[str]:
    """A SQLAlchemy URL whose search_path is a fresh schema, dropped afterwards, so tests never
    touch other tables in the shared ``test`` database."""
    if not port_open(PG_HOST, PG_PORT):
        pytest.skip(f"PostgreSQL is not listening on {PG_HOST}:{PG_PORT}")
    import psycopg

    user = None
    for candidate in ("postgres", "root"):
        try:
            psycopg.connect(
                host=PG_HOST, port=PG_PORT, user=candidate, dbname="test", connect_timeout=3
            ).close()
            user = candidate
            break
        except psycopg.OperationalError:
            continue
    if user is None:
        pytest.skip("PostgreSQL on loopback accepts neither user postgres nor root on db test")
    schema = f"drlaas_t_{uuid.uuid4().hex[:12]}"
    with psycopg.connect(
        host=PG_HOST, port=PG_PORT, user=user, dbname="test", autocommit=True
    ) as c:
        c.execute(f'CREATE SCHEMA "{schema}"')
    try:
        yield (
            f"postgresql+psycopg://{user}@{PG_HOST}:{PG_PORT}/test?options=-csearch_path%3D{schema}"
        )
    finally:
        with psycopg.connect(
            host=PG_HOST, port=PG_PORT, user=user, dbname="test", autocommit=True
        ) as c:
            c.execute(f'DROP SCHEMA "{schema}" CASCADE')
