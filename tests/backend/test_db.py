"""Migrations on SQLite and PostgreSQL: upgrade, round trip, models == migrations, downgrade."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine, inspect, select, text, update
from sqlalchemy.exc import IntegrityError, StatementError

from backend.db import Base, alembic_config, make_engine, make_sessionmaker, upgrade
from backend.db.engine import current_revision, downgrade, include_name
from backend.db.models import AuthNonce, IndexCursor

HEAD = ScriptDirectory.from_config(alembic_config()).get_current_head()


@pytest.fixture(params=["sqlite", "postgresql"])
def engine(request: pytest.FixtureRequest, tmp_path: Path) -> Engine:
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'sub' / 'db.sqlite'}"  # parent dir created on demand
    else:
        url = request.getfixturevalue("pg_url")
    eng = make_engine(url)
    yield eng
    eng.dispose()


def test_single_head_and_linear_history() -> None:
    script = ScriptDirectory.from_config(alembic_config())
    assert len(script.get_heads()) == 1
    assert HEAD is not None


def test_upgrade_creates_tables_and_round_trips_a_nonce(engine: Engine) -> None:
    assert current_revision(engine) is None
    upgrade(engine)
    assert current_revision(engine) == HEAD
    assert {"auth_nonces", "index_cursor"} <= set(inspect(engine).get_table_names())

    sessions = make_sessionmaker(engine)
    issued = dt.datetime(2026, 1, 2, 3, 4, 5, tzinfo=dt.UTC)
    # A non-UTC offset must come back as the same instant, in UTC.
    cet = dt.timezone(dt.timedelta(hours=1))
    with sessions() as s:
        s.add(
            AuthNonce(
                nonce="abcdef0123456789",
                address="0x7E5F4552091A69125d5DfCb7b8C2659029395Bdf",
                issued_at=issued,
                expires_at=(issued + dt.timedelta(minutes=5)).astimezone(cet),
            )
        )
        s.commit()
    with sessions() as s:
        row = s.get(AuthNonce, "abcdef0123456789")
        assert row is not None and row.used_at is None
        assert row.issued_at == issued and row.issued_at.tzinfo is not None
        assert row.expires_at - row.issued_at == dt.timedelta(minutes=5)
        # comparisons against aware "now" values work on both backends (indexed expiry query)
        live = s.scalars(
            select(AuthNonce.nonce).where(AuthNonce.expires_at > issued + dt.timedelta(minutes=4))
        ).all()
        assert live == ["abcdef0123456789"]
        s.execute(
            update(AuthNonce)
            .where(AuthNonce.nonce == "abcdef0123456789")
            .values(used_at=issued + dt.timedelta(seconds=30))
        )
        s.commit()
    with sessions() as s:
        assert s.get(AuthNonce, "abcdef0123456789").used_at == issued + dt.timedelta(seconds=30)
        s.add(
            AuthNonce(nonce="abcdef0123456789", address="0x0", issued_at=issued, expires_at=issued)
        )
        with pytest.raises(IntegrityError):  # single-use: the nonce is the primary key
            s.commit()


def test_index_cursor_round_trip(engine: Engine) -> None:
    upgrade(engine)
    sessions = make_sessionmaker(engine)
    big_block = 2**40  # BigInteger: real chains pass 2**31 blocks' worth of ids
    with sessions() as s:
        s.add(IndexCursor(contract="TMC", address=None, block_number=big_block, log_index=7))
        s.commit()
    with sessions() as s:
        cur = s.get(IndexCursor, "TMC")
        assert (cur.block_number, cur.log_index) == (big_block, 7)
        assert cur.updated_at.tzinfo is not None


def test_models_match_migrations(engine: Engine) -> None:
    """A model change without a migration (or the reverse) shows up as a diff here; tables of
    Celery's result backend sharing the database are not ours and are ignored."""
    upgrade(engine)
    with engine.begin() as conn:
        conn.execute(text("CREATE TABLE celery_taskmeta (id INTEGER PRIMARY KEY)"))
        conn.execute(text("CREATE TABLE stray (id INTEGER PRIMARY KEY)"))
    with engine.connect() as conn:
        ctx = MigrationContext.configure(
            conn, opts={"compare_type": True, "include_name": include_name}
        )
        diff = compare_metadata(ctx, Base.metadata)
    assert [(d[0], d[1].name) for d in diff] == [("remove_table", "stray")]


def test_downgrade_to_base_removes_tables(engine: Engine) -> None:
    upgrade(engine)
    downgrade(engine, "base")
    assert current_revision(engine) is None
    assert not {"auth_nonces", "index_cursor"} & set(inspect(engine).get_table_names())
    upgrade(engine)  # and back again
    assert current_revision(engine) == HEAD


def test_naive_datetimes_are_refused(tmp_path: Path) -> None:
    engine = make_engine(f"sqlite:///{tmp_path / 'db.sqlite'}")
    upgrade(engine)
    with make_sessionmaker(engine)() as s:
        s.add(
            AuthNonce(
                nonce="n" * 16,
                address="0x0",
                issued_at=dt.datetime(2026, 1, 1),
                expires_at=dt.datetime(2026, 1, 1),
            )
        )
        with pytest.raises(StatementError, match="naive datetime"):
            s.commit()
    engine.dispose()
