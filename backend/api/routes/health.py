"""Liveness and a configuration summary (no secrets): which backend each service uses."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from sqlalchemy import text
from sqlalchemy.exc import SQLAlchemyError

from backend.api.deps import SessionDep, SettingsDep
from backend.api.errors import RuleErrorBody
from backend.api.version import VERSION

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


@router.get(
    "",
    response_model=HealthPublic,
    # degraded (this route), or overloaded (the load shedder in front of every route)
    responses={503: {"model": HealthPublic | RuleErrorBody}},
)
def health(settings: SettingsDep, session: SessionDep) -> HealthPublic | JSONResponse:
    """200 when the database answers, 503 with the same body (``degraded``) when it does not."""
    revision: str | None = None
    try:
        session.execute(text("SELECT 1"))
        db_ok = True
        try:
            revision = session.execute(text("SELECT version_num FROM alembic_version")).scalar()
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
