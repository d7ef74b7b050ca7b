"""task specs read after their event: a state and a read count per task

Revision ID: 0004
Revises: 0003
Create Date: 2026-12-04

The indexer no longer reads a task's spec inside the batch of chain events (a description
naming a CID the IPFS node cannot find held every later event for the node's find timeout);
it records the task as ``pending`` and reads the spec afterwards, a bounded number of times.
Tasks indexed before keep the spec they have (``read``); those without one get one more read.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # plain ALTERs, no batch: SQLite adds and drops a column in place (a batch would rebuild
    # ``tasks``, and dropping it deletes the offers and outcomes that reference it)
    state = sa.Column("spec_state", sa.String(length=8), server_default="pending", nullable=False)
    op.add_column("tasks", state)
    tries = sa.Column("spec_tries", sa.Integer(), server_default="0", nullable=False)
    op.add_column("tasks", tries)
    op.create_index(op.f("ix_tasks_spec_state"), "tasks", ["spec_state"], unique=False)
    op.execute("UPDATE tasks SET spec_state = 'read' WHERE spec IS NOT NULL")


def downgrade() -> None:
    op.drop_index(op.f("ix_tasks_spec_state"), table_name="tasks")
    op.drop_column("tasks", "spec_tries")
    op.drop_column("tasks", "spec_state")
