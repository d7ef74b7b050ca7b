"""indexed chain state: events timeline, workers, requesters, tasks, offers, outcomes, reviews,
models, allocations, progress points (written by backend.indexer)

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-22

Plain SQLAlchemy types only (``UTCDateTime`` is stored as a naive UTC ``DateTime``), so the
migration stays frozen when model code changes.
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0002"
down_revision: str | None = "0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "allocations",
        sa.Column("id", sa.BigInteger(), autoincrement=False, nullable=False),
        sa.Column("requester", sa.String(length=42), nullable=False),
        sa.Column("domain", sa.Integer(), nullable=False),
        sa.Column("metric", sa.Integer(), nullable=False),
        sa.Column("num_models", sa.Integer(), nullable=False),
        sa.Column("price_wei", sa.String(length=80), nullable=False),
        sa.Column("block_number", sa.BigInteger(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_allocations")),
    )
    with op.batch_alter_table("allocations", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_allocations_requester"), ["requester"], unique=False)

    op.create_table(
        "chain_events",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("block_number", sa.BigInteger(), nullable=False),
        sa.Column("log_index", sa.Integer(), nullable=False),
        sa.Column("tx_hash", sa.String(length=66), nullable=False),
        sa.Column("contract", sa.String(length=32), nullable=False),
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("args", sa.JSON(), nullable=False),
        sa.Column("block_time", sa.BigInteger(), nullable=True),
        sa.Column("task_id", sa.BigInteger(), nullable=True),
        sa.Column("model_id", sa.BigInteger(), nullable=True),
        sa.Column("alloc_id", sa.BigInteger(), nullable=True),
        sa.Column("account", sa.String(length=42), nullable=True),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_chain_events")),
        sa.UniqueConstraint("block_number", "log_index", name=op.f("uq_chain_events_block_number")),
    )
    with op.batch_alter_table("chain_events", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_chain_events_account"), ["account"], unique=False)
        batch_op.create_index(batch_op.f("ix_chain_events_alloc_id"), ["alloc_id"], unique=False)
        batch_op.create_index(batch_op.f("ix_chain_events_model_id"), ["model_id"], unique=False)
        batch_op.create_index(batch_op.f("ix_chain_events_name"), ["name"], unique=False)
        batch_op.create_index(batch_op.f("ix_chain_events_task_id"), ["task_id"], unique=False)

    op.create_table(
        "index_meta",
        sa.Column("key", sa.String(length=64), nullable=False),
        sa.Column("value", sa.String(length=256), nullable=False),
        sa.PrimaryKeyConstraint("key", name=op.f("pk_index_meta")),
    )
    op.create_table(
        "models",
        sa.Column("id", sa.BigInteger(), autoincrement=False, nullable=False),
        sa.Column("owner", sa.String(length=42), nullable=False),
        sa.Column("domain", sa.Integer(), nullable=False),
        sa.Column("cid", sa.String(length=512), nullable=False),
        sa.Column("description", sa.String(length=2048), nullable=False),
        sa.Column("env", sa.JSON(), nullable=False),
        sa.Column("agents", sa.Integer(), nullable=True),
        sa.Column("walls_min", sa.Integer(), nullable=True),
        sa.Column("walls_max", sa.Integer(), nullable=True),
        sa.Column("alloc_count", sa.BigInteger(), nullable=False),
        sa.Column("total_review", sa.BigInteger(), nullable=False),
        sa.Column("reputation", sa.BigInteger(), nullable=False),
        sa.Column("block_number", sa.BigInteger(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_models")),
    )
    with op.batch_alter_table("models", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_models_agents"), ["agents"], unique=False)
        batch_op.create_index(batch_op.f("ix_models_domain"), ["domain"], unique=False)
        batch_op.create_index("ix_models_domain_reputation", ["domain", "reputation"], unique=False)
        batch_op.create_index(batch_op.f("ix_models_owner"), ["owner"], unique=False)
        batch_op.create_index(batch_op.f("ix_models_reputation"), ["reputation"], unique=False)

    op.create_table(
        "progress_points",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("task_id", sa.BigInteger(), nullable=False),
        sa.Column("worker", sa.String(length=42), nullable=False),
        sa.Column("step", sa.BigInteger(), nullable=False),
        sa.Column("success", sa.Float(), nullable=True),
        sa.Column("time", sa.Float(), nullable=True),
        sa.Column("cost", sa.Float(), nullable=True),
        sa.Column("extra", sa.JSON(), nullable=True),
        sa.Column("created_at", sa.DateTime(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_progress_points")),
        sa.UniqueConstraint("task_id", "worker", "step", name=op.f("uq_progress_points_task_id")),
    )
    with op.batch_alter_table("progress_points", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_progress_points_task_id"), ["task_id"], unique=False)

    op.create_table(
        "requesters",
        sa.Column("address", sa.String(length=42), nullable=False),
        sa.Column("block_number", sa.BigInteger(), nullable=False),
        sa.PrimaryKeyConstraint("address", name=op.f("pk_requesters")),
    )
    op.create_table(
        "reviews",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("kind", sa.String(length=8), nullable=False),
        sa.Column("task_id", sa.BigInteger(), nullable=True),
        sa.Column("alloc_id", sa.BigInteger(), nullable=True),
        sa.Column("model_id", sa.BigInteger(), nullable=True),
        sa.Column("worker", sa.String(length=42), nullable=True),
        sa.Column("review", sa.Integer(), nullable=False),
        sa.Column("accepted", sa.Boolean(), nullable=True),
        sa.Column("block_number", sa.BigInteger(), nullable=False),
        sa.Column("log_index", sa.Integer(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_reviews")),
        sa.UniqueConstraint("block_number", "log_index", name=op.f("uq_reviews_block_number")),
    )
    with op.batch_alter_table("reviews", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_reviews_alloc_id"), ["alloc_id"], unique=False)
        batch_op.create_index(batch_op.f("ix_reviews_model_id"), ["model_id"], unique=False)
        batch_op.create_index(batch_op.f("ix_reviews_task_id"), ["task_id"], unique=False)

    op.create_table(
        "tasks",
        sa.Column("id", sa.BigInteger(), autoincrement=False, nullable=False),
        sa.Column("requester", sa.String(length=42), nullable=False),
        sa.Column("domain", sa.Integer(), nullable=False),
        sa.Column("num_workers", sa.Integer(), nullable=False),
        sa.Column("reward_wei", sa.String(length=80), nullable=False),
        sa.Column("deadline", sa.BigInteger(), nullable=False),
        sa.Column("min_reputation", sa.BigInteger(), nullable=False),
        sa.Column("min_rating", sa.BigInteger(), nullable=False),
        sa.Column("min_cpu_cores", sa.BigInteger(), nullable=False),
        sa.Column("min_ram_gb", sa.BigInteger(), nullable=False),
        sa.Column("description", sa.String(length=512), nullable=False),
        sa.Column("spec", sa.JSON(), nullable=True),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("offered", sa.Integer(), nullable=False),
        sa.Column("block_number", sa.BigInteger(), nullable=False),
        sa.Column("updated_block", sa.BigInteger(), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_tasks")),
    )
    with op.batch_alter_table("tasks", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_tasks_domain"), ["domain"], unique=False)
        batch_op.create_index(batch_op.f("ix_tasks_requester"), ["requester"], unique=False)
        batch_op.create_index(batch_op.f("ix_tasks_status"), ["status"], unique=False)

    op.create_table(
        "workers",
        sa.Column("address", sa.String(length=42), nullable=False),
        sa.Column("worker_id", sa.Integer(), nullable=False),
        sa.Column("domain_mask", sa.String(length=80), nullable=False),
        sa.Column("cpu_cores", sa.BigInteger(), nullable=False),
        sa.Column("ram_gb", sa.BigInteger(), nullable=False),
        sa.Column("gpu_series", sa.Integer(), nullable=False),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("assigned", sa.BigInteger(), nullable=False),
        sa.Column("accepted", sa.BigInteger(), nullable=False),
        sa.Column("completed", sa.BigInteger(), nullable=False),
        sa.Column("rating_sum", sa.BigInteger(), nullable=False),
        sa.Column("rating_count", sa.BigInteger(), nullable=False),
        sa.Column("reputation", sa.BigInteger(), nullable=False),
        sa.Column("rating", sa.BigInteger(), nullable=False),
        sa.Column("sharing_reputation", sa.BigInteger(), nullable=False),
        sa.Column("sharing_rating", sa.BigInteger(), nullable=False),
        sa.Column("block_number", sa.BigInteger(), nullable=False),
        sa.PrimaryKeyConstraint("address", name=op.f("pk_workers")),
    )
    with op.batch_alter_table("workers", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_workers_reputation"), ["reputation"], unique=False)
        batch_op.create_index(batch_op.f("ix_workers_status"), ["status"], unique=False)

    op.create_table(
        "allocation_models",
        sa.Column("alloc_id", sa.BigInteger(), nullable=False),
        sa.Column("model_id", sa.BigInteger(), nullable=False),
        sa.Column("owner", sa.String(length=42), nullable=False),
        sa.Column("qos", sa.BigInteger(), nullable=False),
        sa.Column("review", sa.Integer(), nullable=True),
        sa.ForeignKeyConstraint(
            ["alloc_id"],
            ["allocations.id"],
            name=op.f("fk_allocation_models_alloc_id_allocations"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("alloc_id", "model_id", name=op.f("pk_allocation_models")),
    )
    op.create_table(
        "offers",
        sa.Column("task_id", sa.BigInteger(), nullable=False),
        sa.Column("worker", sa.String(length=42), nullable=False),
        sa.Column("state", sa.String(length=16), nullable=False),
        sa.Column("qos", sa.BigInteger(), nullable=False),
        sa.Column("expiry", sa.BigInteger(), nullable=False),
        sa.Column("block_number", sa.BigInteger(), nullable=False),
        sa.Column("updated_block", sa.BigInteger(), nullable=False),
        sa.ForeignKeyConstraint(
            ["task_id"], ["tasks.id"], name=op.f("fk_offers_task_id_tasks"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("task_id", "worker", name=op.f("pk_offers")),
    )
    with op.batch_alter_table("offers", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_offers_state"), ["state"], unique=False)
        batch_op.create_index(batch_op.f("ix_offers_worker"), ["worker"], unique=False)

    op.create_table(
        "outcomes",
        sa.Column("task_id", sa.BigInteger(), nullable=False),
        sa.Column("worker", sa.String(length=42), nullable=False),
        sa.Column("cid", sa.String(length=512), nullable=False),
        sa.Column("block_number", sa.BigInteger(), nullable=False),
        sa.Column("review", sa.Integer(), nullable=True),
        sa.Column("accepted", sa.Boolean(), nullable=True),
        sa.ForeignKeyConstraint(
            ["task_id"], ["tasks.id"], name=op.f("fk_outcomes_task_id_tasks"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("task_id", "worker", name=op.f("pk_outcomes")),
    )
    op.create_table(
        "worker_counters",
        sa.Column("address", sa.String(length=42), nullable=False),
        sa.Column("domain", sa.Integer(), nullable=False),
        sa.Column("task_type", sa.Integer(), nullable=False),
        sa.Column("assigned", sa.BigInteger(), nullable=False),
        sa.Column("accepted", sa.BigInteger(), nullable=False),
        sa.Column("completed", sa.BigInteger(), nullable=False),
        sa.Column("rating_sum", sa.BigInteger(), nullable=False),
        sa.Column("rating_count", sa.BigInteger(), nullable=False),
        sa.ForeignKeyConstraint(
            ["address"],
            ["workers.address"],
            name=op.f("fk_worker_counters_address_workers"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("address", "domain", "task_type", name=op.f("pk_worker_counters")),
    )
    op.create_table(
        "worker_domains",
        sa.Column("address", sa.String(length=42), nullable=False),
        sa.Column("domain", sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(
            ["address"],
            ["workers.address"],
            name=op.f("fk_worker_domains_address_workers"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("address", "domain", name=op.f("pk_worker_domains")),
    )
    with op.batch_alter_table("worker_domains", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_worker_domains_domain"), ["domain"], unique=False)


def downgrade() -> None:
    with op.batch_alter_table("worker_domains", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_worker_domains_domain"))

    op.drop_table("worker_domains")
    op.drop_table("worker_counters")
    op.drop_table("outcomes")
    with op.batch_alter_table("offers", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_offers_worker"))
        batch_op.drop_index(batch_op.f("ix_offers_state"))

    op.drop_table("offers")
    op.drop_table("allocation_models")
    with op.batch_alter_table("workers", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_workers_status"))
        batch_op.drop_index(batch_op.f("ix_workers_reputation"))

    op.drop_table("workers")
    with op.batch_alter_table("tasks", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_tasks_status"))
        batch_op.drop_index(batch_op.f("ix_tasks_requester"))
        batch_op.drop_index(batch_op.f("ix_tasks_domain"))

    op.drop_table("tasks")
    with op.batch_alter_table("reviews", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_reviews_task_id"))
        batch_op.drop_index(batch_op.f("ix_reviews_model_id"))
        batch_op.drop_index(batch_op.f("ix_reviews_alloc_id"))

    op.drop_table("reviews")
    op.drop_table("requesters")
    with op.batch_alter_table("progress_points", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_progress_points_task_id"))

    op.drop_table("progress_points")
    with op.batch_alter_table("models", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_models_reputation"))
        batch_op.drop_index(batch_op.f("ix_models_owner"))
        batch_op.drop_index("ix_models_domain_reputation")
        batch_op.drop_index(batch_op.f("ix_models_domain"))
        batch_op.drop_index(batch_op.f("ix_models_agents"))

    op.drop_table("models")
    op.drop_table("index_meta")
    with op.batch_alter_table("chain_events", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_chain_events_task_id"))
        batch_op.drop_index(batch_op.f("ix_chain_events_name"))
        batch_op.drop_index(batch_op.f("ix_chain_events_model_id"))
        batch_op.drop_index(batch_op.f("ix_chain_events_alloc_id"))
        batch_op.drop_index(batch_op.f("ix_chain_events_account"))

    op.drop_table("chain_events")
    with op.batch_alter_table("allocations", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_allocations_requester"))

    op.drop_table("allocations")
