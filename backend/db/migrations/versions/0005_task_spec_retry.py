"""task specs not found are asked for again later: when, per task

Revision ID: 0005
Revises: 0004
Create Date: 2026-12-04

A spec the store did not find in ``SPEC_TRIES`` reads was ``missing`` for good, so a requester
whose node was slow or offline for a minute had a task without its environment in every
listing. A ``missing`` task now carries the time of its next read (backing off to an hour).
Those marked missing before get a read at the next poll.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # a plain ALTER, as 0004 (a batch would rebuild ``tasks`` on SQLite)
    op.add_column("tasks", sa.Column("spec_retry_at", sa.BigInteger(), nullable=True))
    op.execute("UPDATE tasks SET spec_retry_at = 0 WHERE spec_state = 'missing'")


def downgrade() -> None:
    op.drop_column("tasks", "spec_retry_at")
