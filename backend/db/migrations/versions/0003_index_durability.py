"""index durability: uint32 chain values in BIGINT columns, an error per unstorable event, hashes
of indexed blocks (to notice a chain that went back)

Revision ID: 0003
Revises: 0002
Create Date: 2026-12-02

The widened columns change on PostgreSQL only, where INTEGER is int32 (one ``ModelAdded`` with
an env value >= 2^31 stopped the indexer there). SQLite's INTEGER already holds 64 bits; the
models declare those columns INTEGER on SQLite, so nothing is copied there (a SQLite ALTER
rebuilds the table, and dropping a parent table with foreign keys on deletes its children).
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

WIDENED = (
    ("workers", "worker_id", False),
    ("worker_counters", "domain", False),
    ("tasks", "domain", False),
    ("models", "domain", False),
    ("models", "agents", True),
    ("models", "walls_min", True),
    ("models", "walls_max", True),
    ("allocations", "domain", False),
)


def _widen(to: sa.types.TypeEngine, existing: sa.types.TypeEngine) -> None:
    if op.get_bind().dialect.name == "sqlite":
        return
    for table, column, nullable in WIDENED:
        op.alter_column(table, column, type_=to, existing_type=existing, existing_nullable=nullable)


def upgrade() -> None:
    _widen(sa.BigInteger(), sa.Integer())
    op.add_column("chain_events", sa.Column("error", sa.String(length=512), nullable=True))
    op.create_table(
        "index_blocks",
        sa.Column("block_number", sa.BigInteger(), autoincrement=False, nullable=False),
        sa.Column("hash", sa.String(length=66), nullable=False),
        sa.PrimaryKeyConstraint("block_number", name=op.f("pk_index_blocks")),
    )


def downgrade() -> None:
    op.drop_table("index_blocks")
    with op.batch_alter_table("chain_events", schema=None) as batch_op:
        batch_op.drop_column("error")
    _widen(sa.Integer(), sa.BigInteger())  # fails on a value >= 2^31, as it should
