"""Indexed workers: list with filters and sorting, and one worker's detail with counters."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Path, Query
from sqlalchemy import func, select

from backend.api.deps import SessionDep
from backend.api.errors import RuleError, rule_responses
from backend.api.schemas import Address, FractionQuery
from backend.db import models as m
from backend.schemas.common import MAX_DOMAIN, from_fixed, to_fixed
from backend.schemas.workers import (
    CountersPublic,
    DomainCountersPublic,
    WorkerDetailPublic,
    WorkerPublic,
    WorkersPublic,
)

router = APIRouter(prefix="/workers", tags=["workers"])

_SORT = {
    "reputation": (m.WorkerRow.reputation.desc(), m.WorkerRow.worker_id),
    "rating": (m.WorkerRow.rating.desc(), m.WorkerRow.worker_id),
    "registered": (m.WorkerRow.worker_id,),
}


def worker_public(w: m.WorkerRow, domains: list[int]) -> WorkerPublic:
    return WorkerPublic(
        address=w.address,
        worker_id=w.worker_id,
        status=w.status,
        domains=domains,
        cpu_cores=w.cpu_cores,
        ram_gb=w.ram_gb,
        gpu_series=w.gpu_series,
        reputation=from_fixed(w.reputation),
        rating=from_fixed(w.rating),
        sharing_reputation=from_fixed(w.sharing_reputation),
        sharing_rating=from_fixed(w.sharing_rating),
        counters=CountersPublic(
            assigned=w.assigned,
            accepted=w.accepted,
            completed=w.completed,
            rating_sum=w.rating_sum,
            rating_count=w.rating_count,
        ),
    )


def _domains(session: SessionDep, addresses: list[str]) -> dict[str, list[int]]:
    out: dict[str, list[int]] = {a: [] for a in addresses}
    if addresses:
        rows = session.execute(
            select(m.WorkerDomain.address, m.WorkerDomain.domain)
            .where(m.WorkerDomain.address.in_(addresses))
            .order_by(m.WorkerDomain.domain)
        )
        for address, domain in rows:
            out[address].append(domain)
    return out


@router.get("", response_model=WorkersPublic)
def list_workers(
    session: SessionDep,
    domain: Annotated[int | None, Query(ge=0, le=MAX_DOMAIN)] = None,
    status: Literal["active", "idle", "pending", "removed"] | None = None,
    min_reputation: FractionQuery = None,
    sort: Literal["reputation", "rating", "registered"] = "reputation",
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
    offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0,
) -> WorkersPublic:
    """Workers matching every given filter, best first by ``sort``."""
    q = select(m.WorkerRow)
    if domain is not None:
        q = q.where(
            m.WorkerRow.address.in_(
                select(m.WorkerDomain.address).where(m.WorkerDomain.domain == domain)
            )
        )
    if status is not None:
        q = q.where(m.WorkerRow.status == status)
    if min_reputation is not None:
        q = q.where(m.WorkerRow.reputation >= to_fixed(min_reputation))
    count = session.scalar(select(func.count()).select_from(q.subquery())) or 0
    rows = session.scalars(q.order_by(*_SORT[sort]).limit(limit).offset(offset)).all()
    doms = _domains(session, [w.address for w in rows])
    return WorkersPublic(data=[worker_public(w, doms[w.address]) for w in rows], count=count)


@router.get("/{address}", response_model=WorkerDetailPublic, responses=rule_responses(404))
def get_worker(address: Annotated[Address, Path()], session: SessionDep) -> WorkerDetailPublic:
    """One worker with its counters per (domain, task type)."""
    w = session.get(m.WorkerRow, address)
    if w is None:
        raise RuleError(404, "worker_not_found", f"{address} is not a registered worker")
    counters = session.scalars(
        select(m.WorkerCounters)
        .where(m.WorkerCounters.address == address)
        .order_by(m.WorkerCounters.domain, m.WorkerCounters.task_type)
    ).all()
    base = worker_public(w, _domains(session, [address])[address])
    return WorkerDetailPublic(
        **base.model_dump(),
        by_domain=[
            DomainCountersPublic(
                domain=c.domain,
                task_type="training" if c.task_type == 0 else "sharing",
                assigned=c.assigned,
                accepted=c.accepted,
                completed=c.completed,
                rating_sum=c.rating_sum,
                rating_count=c.rating_count,
            )
            for c in counters
        ],
    )
