"""Database layer: SQLAlchemy 2.x engine and session factory, declarative ``Base``, migrations.

SQLite (embedded, default) and PostgreSQL via psycopg 3 run the same alembic migrations
(``backend/db/migrations``); tables are never created with ``create_all`` outside tests, so a
deployed schema always equals ``alembic upgrade head``.
"""

from __future__ import annotations

from .base import Base, UTCDateTime, utcnow
from .engine import alembic_config, make_engine, make_sessionmaker, upgrade

__all__ = [
    "Base",
    "UTCDateTime",
    "alembic_config",
    "make_engine",
    "make_sessionmaker",
    "upgrade",
    "utcnow",
]
