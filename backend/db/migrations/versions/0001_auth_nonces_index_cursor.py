"""auth nonces (EIP-4361 sign-in) and the indexer's per-contract cursor

Revision ID: 0001
Revises:
Create Date: 2026-11-22

Datetimes are stored as naive UTC (``sa.DateTime``), the storage form of
``backend.db.base.UTCDateTime``; migrations use plain SQLAlchemy types so they stay frozen even
if the model code changes.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0001"
down_revision: str | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "auth_nonces",
        sa.Column("nonce", sa.String(length=64), nullable=False),
        sa.Column("address", sa.String(length=42), nullable=False),
        sa.Column("issued_at", sa.DateTime(), nullable=False),
        sa.Column("expires_at", sa.DateTime(), nullable=False),
        sa.Column("used_at", sa.DateTime(), nullable=True),
        sa.PrimaryKeyConstraint("nonce", name=op.f("pk_auth_nonces")),
    )
    op.create_index(op.f("ix_auth_nonces_address"), "auth_nonces", ["address"])
    op.create_index(op.f("ix_auth_nonces_expires_at"), "auth_nonces", ["expires_at"])

    op.create_table(
        "index_cursor",
        sa.Column("contract", sa.String(length=64), nullable=False),
        sa.Column("address", sa.String(length=42), nullable=True),
        sa.Column("block_number", sa.BigInteger(), nullable=False),
        sa.Column("log_index", sa.Integer(), nullable=False),
        sa.Column("updated_at", sa.DateTime(), nullable=False),
        sa.PrimaryKeyConstraint("contract", name=op.f("pk_index_cursor")),
    )


def downgrade() -> None:
    op.drop_table("index_cursor")
    op.drop_index(op.f("ix_auth_nonces_expires_at"), table_name="auth_nonces")
    op.drop_index(op.f("ix_auth_nonces_address"), table_name="auth_nonces")
    op.drop_table("auth_nonces")
