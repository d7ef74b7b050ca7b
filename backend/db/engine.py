"""Engine/session factories and programmatic alembic (no alembic.ini on disk is needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from sqlalchemy import Engine, ExceptionContext, create_engine, event, make_url, text
from sqlalchemy.exc import DBAPIError, OperationalError
from sqlalchemy.orm import Session, sessionmaker

from backend.errors import Unavailable

MIGRATIONS_DIR = Path(__file__).with_name("migrations")
#: Tables owned by other libraries in the same database (Celery's result backend on
#: PostgreSQL, kombu's SQL transport): never ours to create or drop.
FOREIGN_TABLE_PREFIXES = ("celery_", "kombu_")


def include_name(name: str | None, type_: str, _parent: object) -> bool:
    """Alembic filter: autogenerate ignores tables of :data:`FOREIGN_TABLE_PREFIXES`."""
    return not (type_ == "table" and name is not None and name.startswith(FOREIGN_TABLE_PREFIXES))


def pool_options(settings: Any) -> dict[str, Any]:
    """Connection pool of a serving process, from settings (``db_pool_size``,
    ``db_max_overflow``, ``db_pool_timeout_s``): a pool that is exhausted makes the waiting
    request fail after ``pool_timeout`` (the gateway answers 503 + Retry-After), instead of
    SQLAlchemy's 30 s wait."""
    return {
        "pool_size": settings.db_pool_size,
        "max_overflow": settings.db_max_overflow,
        "pool_timeout": settings.db_pool_timeout_s,
    }


def make_engine(url: str, **kwargs: Any) -> Engine:
    """An engine for ``url``; SQLite gets WAL, a busy timeout and enforced foreign keys so that
    the gateway, indexer and workers can share one file. ``kwargs`` go to ``create_engine``
    (pool options are dropped for in-memory SQLite, which keeps one connection)."""
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite":
        if parsed.database and parsed.database != ":memory:":
            Path(parsed.database).expanduser().parent.mkdir(parents=True, exist_ok=True)
        else:
            for name in ("pool_size", "max_overflow", "pool_timeout"):
                kwargs.pop(name, None)
        connect_args = {"check_same_thread": False, "timeout": 30.0}
        connect_args.update(kwargs.pop("connect_args", {}))
        engine = create_engine(url, connect_args=connect_args, **kwargs)

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA foreign_keys=ON")
            if parsed.database and parsed.database != ":memory:":
                cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA busy_timeout=30000")
            cur.close()

        return engine
    kwargs.setdefault("pool_pre_ping", True)
    engine = create_engine(url, **kwargs)
    event.listen(engine, "handle_error", _unreachable_is_unavailable)
    return engine


DB_RETRY_AFTER_S = 5
"""Retry-After of a request that found the database unreachable."""


class DatabaseUnavailable(Unavailable, OperationalError):
    """The database server cannot be reached (refused, reset, terminated): an
    ``OperationalError`` (what every ``except SQLAlchemyError`` expects) that is also the domain
    error ``Unavailable``, which the gateway answers 503 with Retry-After (it answered 500
    ``internal_error`` while PostgreSQL was down or restarting)."""

    def __init__(self, error: DBAPIError) -> None:
        Exception.__init__(self, str(error.orig))
        self.rule, self.msg, self.retry_after = (
            "database_unavailable", "the database is unreachable; retry later", DB_RETRY_AFTER_S)
        self.statement, self.params, self.orig = error.statement, error.params, error.orig
        self.hide_parameters, self.ismulti = True, error.ismulti
        self.connection_invalidated, self.detail = error.connection_invalidated, []
        self.code = error.code


def _unreachable_is_unavailable(context: ExceptionContext) -> None:
    """``handle_error`` of server databases: a lost or refused connection raises
    :class:`DatabaseUnavailable` (the connection is invalidated all the same; a pool pre-ping is
    left alone, it reconnects)."""
    error = context.sqlalchemy_exception
    if context.is_pre_ping or not isinstance(error, OperationalError):
        return
    if context.is_disconnect or context.connection is None:  # lost, or could not connect
        raise DatabaseUnavailable(error)


def make_sessionmaker(engine: Engine) -> sessionmaker[Session]:
    """Sessions that keep loaded values after commit (routes serialise after committing)."""
    return sessionmaker(bind=engine, expire_on_commit=False)


def alembic_config(url: str | None = None) -> Config:
    """An alembic ``Config`` built in code (no alembic.ini): script location is this package's
    migrations. From a shell: ``python -m backend.db upgrade`` or ``... revision -m MSG``."""
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    if url is not None:
        cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return cfg


MIGRATION_LOCK = 0x44524C4141530001
"""PostgreSQL advisory lock key (``DRLAAS`` + 1) that :func:`upgrade` holds for its transaction."""


def upgrade(engine: Engine, revision: str = "head") -> None:
    """Migrate the database behind ``engine`` to ``revision`` in one transaction. On PostgreSQL
    the transaction first takes an advisory lock, so two gateways starting at once on one
    database migrate one after the other (the second finds it at ``revision``): both used to
    run the same CREATE TABLEs and the second failed to start on a duplicate key."""
    cfg = alembic_config()
    with engine.begin() as connection:
        if connection.dialect.name == "postgresql":
            connection.execute(text("SELECT pg_advisory_xact_lock(:key)"),
                               {"key": MIGRATION_LOCK})
        cfg.attributes["connection"] = connection
        command.upgrade(cfg, revision)


def downgrade(engine: Engine, revision: str) -> None:
    cfg = alembic_config()
    with engine.begin() as connection:
        cfg.attributes["connection"] = connection
        command.downgrade(cfg, revision)


def current_revision(engine: Engine) -> str | None:
    from alembic.runtime.migration import MigrationContext

    with engine.connect() as connection:
        return MigrationContext.configure(connection).get_current_revision()
