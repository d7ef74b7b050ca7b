"""Tables of the platform foundation. Resource tables (tasks, workers, models) come with the
indexer; each table here has its migration in ``migrations/versions``."""

from __future__ import annotations

import datetime as dt

from sqlalchemy import BigInteger, Integer, String
from sqlalchemy.orm import Mapped, mapped_column

from .base import Base, UTCDateTime, utcnow


class AuthNonce(Base):
    """A single-use EIP-4361 sign-in nonce issued to ``address`` (used once, then ``used_at``)."""

    __tablename__ = "auth_nonces"

    nonce: Mapped[str] = mapped_column(String(64), primary_key=True)
    address: Mapped[str] = mapped_column(String(42), index=True)
    issued_at: Mapped[dt.datetime] = mapped_column(UTCDateTime())
    expires_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), index=True)
    used_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime(), default=None)


class IndexCursor(Base):
    """Where the indexer stopped for one contract: the last fully processed event is
    (``block_number``, ``log_index``); after a restart it resumes right after it."""

    __tablename__ = "index_cursor"

    contract: Mapped[str] = mapped_column(String(64), primary_key=True)
    address: Mapped[str | None] = mapped_column(String(42), default=None)
    """Deployment the cursor belongs to: a cursor for another address must not be resumed."""
    block_number: Mapped[int] = mapped_column(BigInteger)
    log_index: Mapped[int] = mapped_column(Integer)
    updated_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow, onupdate=utcnow)
