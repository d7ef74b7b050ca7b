"""Liveness and a configuration summary (no secrets): which backend each service uses; and the
chain events the index kept without their rows (``chain_events.error``), so an operator sees
what the listings lack without reading the database."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field
from sqlalchemy import func, select, text
from sqlalchemy.exc import SQLAlchemyError

from backend.api.deps import SessionDep, SettingsDep
from backend.api.errors import RuleErrorBody
from backend.api.version import VERSION
from backend.db import models as m
from backend.schemas.common import EventPublic, ListPublic

router = APIRouter(prefix="/health", tags=["health"])


class Services(BaseModel):
    chain: Literal["embedded", "rpc"]
    ipfs: Literal["embedded", "rpc"]
    broker: Literal["embedded", "redis", "amqp"]
    database: Literal["sqlite", "postgresql"]


class HealthPublic(BaseModel):
    status: Literal["ok", "degraded"]
    version: str
    mode: Literal["development", "production"]
    database: Literal["ok", "unavailable"]
    schema_revision: str | None
    services: Services
    index_errors: int | None = Field(
        description="chain events the index kept without their rows (listed at "
        "/api/health/index-errors); null when the database is unavailable"
    )


@router.get(
    "",
    response_model=HealthPublic,
    # degraded (this route), or overloaded (the load shedder in front of every route)
    responses={503: {"model": HealthPublic | RuleErrorBody}},
)
def health(settings: SettingsDep, session: SessionDep) -> HealthPublic | JSONResponse:
    """200 when the database answers, 503 with the same body (``degraded``) when it does not."""
    revision: str | None = None
    index_errors: int | None = None
    try:
        session.execute(text("SELECT 1"))
        db_ok = True
        try:
            revision = session.execute(text("SELECT version_num FROM alembic_version")).scalar()
            index_errors = session.scalar(
                select(func.count()).select_from(m.ChainEvent).where(m.ChainEvent.error.is_not(None))
            )
        except SQLAlchemyError:  # not migrated yet
            session.rollback()
    except SQLAlchemyError:
        db_ok = False
    body = HealthPublic(
        status="ok" if db_ok else "degraded",
        version=VERSION,
        mode=settings.mode,
        database="ok" if db_ok else "unavailable",
        schema_revision=revision,
        index_errors=index_errors,
        services=Services(
            chain=settings.chain_service.kind,  # type: ignore[arg-type]
            ipfs=settings.ipfs_service.kind,  # type: ignore[arg-type]
            broker=settings.broker_service.kind,  # type: ignore[arg-type]
            database="sqlite" if settings.database_url.startswith("sqlite") else "postgresql",
        ),
    )
    if not db_ok:
        return JSONResponse(status_code=503, content=body.model_dump())
    return body


@router.get("/index-errors", response_model=ListPublic[EventPublic])
def index_errors(
    session: SessionDep,
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
    offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0,
) -> ListPublic[EventPublic]:
    """The chain events whose rows the index could not store, newest first, each with its
    ``error`` (the index went on without them; the chain still holds the events)."""
    failed = select(m.ChainEvent).where(m.ChainEvent.error.is_not(None))
    count = session.scalar(select(func.count()).select_from(failed.subquery())) or 0
    rows = session.scalars(
        failed.order_by(m.ChainEvent.block_number.desc(), m.ChainEvent.log_index.desc())
        .limit(limit)
        .offset(offset)
    ).all()
    return ListPublic[EventPublic](
        data=[EventPublic.model_validate(e) for e in rows],
        count=count,
    )
