"""Tables of the platform: sign-in nonces, the indexer cursor (0001), the indexed chain state
(0002) and its uint32-wide columns, event errors and indexed block hashes (0003); each table here
has its migration in ``migrations/versions``."""

from __future__ import annotations

import datetime as dt
from typing import Any

from sqlalchemy import JSON, BigInteger, Float, ForeignKey, Index, Integer, String, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column

from .base import Base, UTCDateTime, utcnow

#: A chain uint32 (or any value up to int64): BIGINT, since PostgreSQL's INTEGER is int32 and one
#: event with a larger value stopped the indexer; SQLite's INTEGER already holds 64 bits, so
#: there the column keeps its type (0003 alters PostgreSQL only: a SQLite ALTER copies the table,
#: and dropping a parent table cascades to its children's rows).
UINT32 = BigInteger().with_variant(Integer(), "sqlite")


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


# -- indexed chain state (migration 0002) --------------------------------------------------------
# Everything below is derived from contract events by ``backend.indexer`` and can be rebuilt
# from the chain at any time; amounts in wei are decimal strings (uint96/uint256 overflow
# BIGINT), QoS values are the contracts' fixed point (ONE = 1e6, backend.chain.qos). Every integer
# column holds what its event type allows (uint32 and below as they are; ids are the contracts'
# counters; a uint256 QoS beyond int64 is clamped by the indexer, the event's args keep it).


class IndexMeta(Base):
    """Key/value facts about the indexed chain, e.g. ``anchor`` = hash of the block that deployed
    the UMC: a different anchor means another chain (a restarted embedded chain), so the index is
    rebuilt instead of mixing two histories."""

    __tablename__ = "index_meta"

    key: Mapped[str] = mapped_column(String(64), primary_key=True)
    value: Mapped[str] = mapped_column(String(256))


class ChainEvent(Base):
    """One decoded contract event (the timeline); unique on (block, log index) so re-processing a
    block after a restart inserts nothing twice."""

    __tablename__ = "chain_events"
    __table_args__ = (UniqueConstraint("block_number", "log_index"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    block_number: Mapped[int] = mapped_column(BigInteger)
    log_index: Mapped[int] = mapped_column(Integer)
    tx_hash: Mapped[str] = mapped_column(String(66))
    contract: Mapped[str] = mapped_column(String(32))
    name: Mapped[str] = mapped_column(String(64), index=True)
    args: Mapped[dict[str, Any]] = mapped_column(JSON)
    block_time: Mapped[int | None] = mapped_column(BigInteger, default=None)
    task_id: Mapped[int | None] = mapped_column(BigInteger, index=True, default=None)
    model_id: Mapped[int | None] = mapped_column(BigInteger, index=True, default=None)
    alloc_id: Mapped[int | None] = mapped_column(BigInteger, index=True, default=None)
    account: Mapped[str | None] = mapped_column(String(42), index=True, default=None)
    error: Mapped[str | None] = mapped_column(String(512), default=None)
    """Why the event's rows could not be stored (the index went on without them), else None."""


class IndexBlock(Base):
    """Hash of a recently indexed block (the cursor's and those with events): a chain whose block
    at that height differs (a reorg, an embedded chain that lost its last blocks) is re-indexed
    from the last block that still matches."""

    __tablename__ = "index_blocks"

    block_number: Mapped[int] = mapped_column(BigInteger, primary_key=True, autoincrement=False)
    hash: Mapped[str] = mapped_column(String(66))


class Requester(Base):
    __tablename__ = "requesters"

    address: Mapped[str] = mapped_column(String(42), primary_key=True)
    block_number: Mapped[int] = mapped_column(BigInteger)


class WorkerRow(Base):
    """A registered worker; training counters summed over domains with Eq. 19 reputation and the
    7.5.1 rating, and the model-sharing ones (Eq. 19 over sharing counters) for model search."""

    __tablename__ = "workers"

    address: Mapped[str] = mapped_column(String(42), primary_key=True)
    worker_id: Mapped[int] = mapped_column(UINT32)
    domain_mask: Mapped[str] = mapped_column(String(80))
    cpu_cores: Mapped[int] = mapped_column(BigInteger)
    ram_gb: Mapped[int] = mapped_column(BigInteger)
    gpu_series: Mapped[int] = mapped_column(Integer)
    status: Mapped[str] = mapped_column(String(16), index=True)
    assigned: Mapped[int] = mapped_column(BigInteger, default=0)
    accepted: Mapped[int] = mapped_column(BigInteger, default=0)
    completed: Mapped[int] = mapped_column(BigInteger, default=0)
    rating_sum: Mapped[int] = mapped_column(BigInteger, default=0)
    rating_count: Mapped[int] = mapped_column(BigInteger, default=0)
    reputation: Mapped[int] = mapped_column(BigInteger, index=True)
    rating: Mapped[int] = mapped_column(BigInteger)
    sharing_reputation: Mapped[int] = mapped_column(BigInteger)
    sharing_rating: Mapped[int] = mapped_column(BigInteger)
    block_number: Mapped[int] = mapped_column(BigInteger)


class WorkerDomain(Base):
    __tablename__ = "worker_domains"

    address: Mapped[str] = mapped_column(
        String(42), ForeignKey("workers.address", ondelete="CASCADE"), primary_key=True
    )
    domain: Mapped[int] = mapped_column(Integer, primary_key=True, index=True)


class WorkerCounters(Base):
    """UMC counters of one (worker, domain, task type), as the last WorkerInfoUpdated said."""

    __tablename__ = "worker_counters"

    address: Mapped[str] = mapped_column(
        String(42), ForeignKey("workers.address", ondelete="CASCADE"), primary_key=True
    )
    domain: Mapped[int] = mapped_column(UINT32, primary_key=True)
    task_type: Mapped[int] = mapped_column(Integer, primary_key=True)
    assigned: Mapped[int] = mapped_column(BigInteger)
    accepted: Mapped[int] = mapped_column(BigInteger)
    completed: Mapped[int] = mapped_column(BigInteger)
    rating_sum: Mapped[int] = mapped_column(BigInteger)
    rating_count: Mapped[int] = mapped_column(BigInteger)


class TaskRow(Base):
    __tablename__ = "tasks"

    id: Mapped[int] = mapped_column(BigInteger, primary_key=True, autoincrement=False)
    requester: Mapped[str] = mapped_column(String(42), index=True)
    domain: Mapped[int] = mapped_column(UINT32, index=True)
    num_workers: Mapped[int] = mapped_column(Integer)
    reward_wei: Mapped[str] = mapped_column(String(80))
    deadline: Mapped[int] = mapped_column(BigInteger)
    min_reputation: Mapped[int] = mapped_column(BigInteger)
    min_rating: Mapped[int] = mapped_column(BigInteger)
    min_cpu_cores: Mapped[int] = mapped_column(BigInteger)
    min_ram_gb: Mapped[int] = mapped_column(BigInteger)
    description: Mapped[str] = mapped_column(String(512))
    spec: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    spec_state: Mapped[str] = mapped_column(
        String(8), default="pending", server_default="pending", index=True
    )
    """pending (to be read from the store), read, none (the description is no CID), invalid (no
    task spec), missing (not found in ``SPEC_TRIES`` reads; read again at ``spec_retry_at``):
    backend.indexer."""
    spec_tries: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    spec_retry_at: Mapped[int | None] = mapped_column(BigInteger, default=None)
    """Unix time of a ``missing`` spec's next read (migration 0005)."""
    status: Mapped[str] = mapped_column(String(16), index=True)
    offered: Mapped[int] = mapped_column(Integer, default=0)
    block_number: Mapped[int] = mapped_column(BigInteger)
    updated_block: Mapped[int] = mapped_column(BigInteger)


class OfferRow(Base):
    __tablename__ = "offers"

    task_id: Mapped[int] = mapped_column(
        BigInteger, ForeignKey("tasks.id", ondelete="CASCADE"), primary_key=True
    )
    worker: Mapped[str] = mapped_column(String(42), primary_key=True, index=True)
    state: Mapped[str] = mapped_column(String(16), index=True)
    qos: Mapped[int] = mapped_column(BigInteger)
    expiry: Mapped[int] = mapped_column(BigInteger)
    block_number: Mapped[int] = mapped_column(BigInteger)
    updated_block: Mapped[int] = mapped_column(BigInteger)


class OutcomeRow(Base):
    __tablename__ = "outcomes"

    task_id: Mapped[int] = mapped_column(
        BigInteger, ForeignKey("tasks.id", ondelete="CASCADE"), primary_key=True
    )
    worker: Mapped[str] = mapped_column(String(42), primary_key=True)
    cid: Mapped[str] = mapped_column(String(512))
    block_number: Mapped[int] = mapped_column(BigInteger)
    review: Mapped[int | None] = mapped_column(Integer, default=None)
    accepted: Mapped[bool | None] = mapped_column(default=None)


class ReviewRow(Base):
    """A requester's review: of a training outcome (``kind='task'``) or an allocated model."""

    __tablename__ = "reviews"
    __table_args__ = (UniqueConstraint("block_number", "log_index"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    kind: Mapped[str] = mapped_column(String(8))
    task_id: Mapped[int | None] = mapped_column(BigInteger, index=True, default=None)
    alloc_id: Mapped[int | None] = mapped_column(BigInteger, index=True, default=None)
    model_id: Mapped[int | None] = mapped_column(BigInteger, index=True, default=None)
    worker: Mapped[str | None] = mapped_column(String(42), default=None)
    review: Mapped[int] = mapped_column(Integer)
    accepted: Mapped[bool | None] = mapped_column(default=None)
    block_number: Mapped[int] = mapped_column(BigInteger)
    log_index: Mapped[int] = mapped_column(Integer)


class ModelRow(Base):
    """A shared model (MMC); env attributes decoded by ``backend.services.envattrs``; Eq. 11
    reputation kept in fixed point for sorting and filtering."""

    __tablename__ = "models"
    __table_args__ = (Index("ix_models_domain_reputation", "domain", "reputation"),)

    id: Mapped[int] = mapped_column(BigInteger, primary_key=True, autoincrement=False)
    owner: Mapped[str] = mapped_column(String(42), index=True)
    domain: Mapped[int] = mapped_column(UINT32, index=True)
    cid: Mapped[str] = mapped_column(String(512))
    description: Mapped[str] = mapped_column(String(2048))
    env: Mapped[list[int]] = mapped_column(JSON)
    agents: Mapped[int | None] = mapped_column(UINT32, index=True, default=None)
    walls_min: Mapped[int | None] = mapped_column(UINT32, default=None)
    walls_max: Mapped[int | None] = mapped_column(UINT32, default=None)
    alloc_count: Mapped[int] = mapped_column(BigInteger, default=0)
    total_review: Mapped[int] = mapped_column(BigInteger, default=0)
    reputation: Mapped[int] = mapped_column(BigInteger, index=True)
    block_number: Mapped[int] = mapped_column(BigInteger)


class AllocationRow(Base):
    __tablename__ = "allocations"

    id: Mapped[int] = mapped_column(BigInteger, primary_key=True, autoincrement=False)
    requester: Mapped[str] = mapped_column(String(42), index=True)
    domain: Mapped[int] = mapped_column(UINT32)
    metric: Mapped[int] = mapped_column(Integer)
    num_models: Mapped[int] = mapped_column(Integer)
    price_wei: Mapped[str] = mapped_column(String(80))
    block_number: Mapped[int] = mapped_column(BigInteger)


class AllocatedModel(Base):
    __tablename__ = "allocation_models"

    alloc_id: Mapped[int] = mapped_column(
        BigInteger, ForeignKey("allocations.id", ondelete="CASCADE"), primary_key=True
    )
    model_id: Mapped[int] = mapped_column(BigInteger, primary_key=True)
    owner: Mapped[str] = mapped_column(String(42))
    qos: Mapped[int] = mapped_column(BigInteger)
    review: Mapped[int | None] = mapped_column(Integer, default=None)


class ProgressPoint(Base):
    """A live training-curve point posted by an assigned worker (not from the chain)."""

    __tablename__ = "progress_points"
    __table_args__ = (UniqueConstraint("task_id", "worker", "step"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    task_id: Mapped[int] = mapped_column(BigInteger, index=True)
    worker: Mapped[str] = mapped_column(String(42))
    step: Mapped[int] = mapped_column(BigInteger)
    success: Mapped[float | None] = mapped_column(Float, default=None)
    time: Mapped[float | None] = mapped_column(Float, default=None)
    cost: Mapped[float | None] = mapped_column(Float, default=None)
    extra: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime(), default=utcnow)
