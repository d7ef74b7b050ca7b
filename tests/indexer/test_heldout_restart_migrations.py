"""Held-out pass (restarts and real services): migrations of a database in use.

* Two gateways started at once on one fresh PostgreSQL database (``migrate_on_start``) ran the
  same CREATE TABLEs in two transactions; the second failed to start on a duplicate key
  (``pg_type_typname_nsp_index``). ``upgrade`` now takes an advisory lock first.
* ``upgrade head`` of a database written by an earlier version keeps its rows, and the indexer
  goes on from its cursor without indexing an event twice.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import event, select, text
from sqlalchemy.orm import Session, sessionmaker

from backend.db import make_engine, make_sessionmaker, upgrade
from backend.db import models as m
from backend.db.engine import current_revision, downgrade
from backend.indexer import Indexer
from backend.services.chain import ChainService
from tests.gateway.test_indexer import _activity, _chain_events, _indexed

REPO = Path(__file__).resolve().parents[2]
UPGRADE = ("import sys; from backend.db import make_engine, upgrade; "
           "upgrade(make_engine(sys.argv[1]))")


@pytest.fixture
def pg(request: pytest.FixtureRequest) -> str:
    from tests.backend.conftest import pg_url

    gen = pg_url.__wrapped__()  # a fresh schema, dropped after
    url = next(gen)
    request.addfinalizer(lambda: next(gen, None))
    return url


def _waiting_on_a_lock(url: str) -> bool:
    engine = make_engine(url)
    try:
        with engine.connect() as c:
            return bool(c.scalar(text(
                "SELECT count(*) FROM pg_stat_activity WHERE datname = current_database() "
                "AND wait_event_type = 'Lock' AND pid <> pg_backend_pid() "
                "AND application_name = 'drlaas-second-gateway'")))
    finally:
        engine.dispose()


def test_two_gateways_migrating_one_fresh_postgresql_database_at_once_both_start(pg: str) -> None:
    first = make_engine(pg)
    paused, go_on = threading.Event(), threading.Event()

    @event.listens_for(first, "after_cursor_execute")
    def _pause(conn: Any, cursor: Any, statement: str, *args: Any) -> None:
        if statement.lstrip().upper().startswith("CREATE TABLE") and not paused.is_set():
            paused.set()  # the first gateway is inside its migration, not committed yet
            go_on.wait(120)

    errors: list[BaseException] = []

    def migrate_first() -> None:
        try:
            upgrade(first)
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    t = threading.Thread(target=migrate_first)
    t.start()
    assert paused.wait(60)
    second_url = pg + "&application_name=drlaas-second-gateway"
    second = subprocess.Popen([sys.executable, "-c", UPGRADE, second_url], cwd=REPO,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60  # until the second waits on the first (no timing assert)
        while not _waiting_on_a_lock(pg) and second.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        go_on.set()
        t.join(60)
    _, err = second.communicate(timeout=120)
    assert not errors
    assert second.returncode == 0, err.strip().splitlines()[-1:]
    assert current_revision(first) == current_revision(make_engine(pg)) is not None
    first.dispose()


@pytest.mark.parametrize("kind", ["sqlite", "postgresql"])
def test_upgrade_of_an_index_of_the_previous_version_keeps_its_rows(
    service: ChainService, tmp_path: Path, request: pytest.FixtureRequest, kind: str
) -> None:
    if kind == "sqlite":
        url = f"sqlite:///{tmp_path / 'idx.sqlite'}"
    else:
        url = request.getfixturevalue("pg")
    engine = make_engine(url)
    upgrade(engine)
    sessions: sessionmaker[Session] = make_sessionmaker(engine)
    offers: list[tuple[int, str]] = []
    Indexer(service, sessions, on_offer=lambda t, w: offers.append((t, w))).poll()
    _activity(service, 1)
    Indexer(service, sessions, on_offer=lambda t, w: offers.append((t, w))).poll()
    with sessions() as s:
        before = {t.__tablename__: len(s.scalars(select(t)).all())
                  for t in (m.TaskRow, m.OfferRow, m.WorkerRow, m.ChainEvent, m.IndexCursor)}
    downgrade(engine, "0002")  # the database as the first release left it, rows and all
    engine.dispose()

    engine = make_engine(url)
    upgrade(engine)  # the new release starts on it
    sessions = make_sessionmaker(engine)
    with sessions() as s:
        after = {t.__tablename__: len(s.scalars(select(t)).all())
                 for t in (m.TaskRow, m.OfferRow, m.WorkerRow, m.ChainEvent, m.IndexCursor)}
    assert after == before and before["tasks"] == 1 and before["offers"] == 2
    _activity(service, 5)
    Indexer(service, sessions, on_offer=lambda t, w: offers.append((t, w))).poll()
    assert _indexed(sessions) == _chain_events(service)
    assert len(offers) == len(set(offers)) == 4  # no offer handed over twice across the upgrade
    engine.dispose()
