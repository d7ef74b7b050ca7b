"""Held-out pass (restarts and real services): two gateways indexing one database. The
indexer that loses the race for a range (the other committed it between its reads and its
writes) raised the unique violation of ``chain_events`` out of ``poll``, logged by the
indexer thread as a failed poll with its traceback at every collision; it now goes on from the
winner's cursor. Every event is indexed once and every offer handed over once either way."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy.orm import Session, sessionmaker

from backend.db import make_engine, make_sessionmaker, upgrade
from backend.indexer import Indexer
from backend.services.chain import ChainService
from tests.gateway.test_indexer import _activity, _chain_events, _indexed


@pytest.fixture(params=["sqlite", "postgresql"])
def two_sessions(
    request: pytest.FixtureRequest, tmp_path: Path
) -> tuple[sessionmaker[Session], sessionmaker[Session]]:
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'idx.sqlite'}"
    else:
        from tests.backend.conftest import pg_url

        gen = pg_url.__wrapped__()
        url = next(gen)
        request.addfinalizer(lambda: next(gen, None))
    engines = make_engine(url), make_engine(url)  # two processes' pools
    upgrade(engines[0])
    for e in engines:
        request.addfinalizer(e.dispose)
    return make_sessionmaker(engines[0]), make_sessionmaker(engines[1])


def test_the_indexer_that_loses_a_race_for_a_range_goes_on(
    service: ChainService,
    two_sessions: tuple[sessionmaker[Session], sessionmaker[Session]],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    offers: list[tuple[int, str]] = []
    hook: Callable[[int, str], None] = lambda t, w: offers.append((t, w))  # noqa: E731
    a = Indexer(service, two_sessions[0], on_offer=hook)
    b = Indexer(service, two_sessions[1], on_offer=hook)
    a.poll()
    _activity(service, 1)
    real_record = b._record
    raced: list[bool] = []

    def record_after_the_other_committed(*args: Any, **kwargs: Any) -> Any:
        if not raced:  # b has read the range and found none of it indexed; a indexes it now
            raced.append(True)
            a.poll()
        return real_record(*args, **kwargs)

    monkeypatch.setattr(b, "_record", record_after_the_other_committed)
    b.poll()  # raised IntegrityError before the fix
    assert raced
    assert b.cursor() == a.cursor() and b.cursor()[0] == service.block_number()
    assert _indexed(two_sessions[1]) == _chain_events(service)
    assert len(offers) == len(set(offers)) == 2
