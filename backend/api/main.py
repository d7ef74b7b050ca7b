"""App factory: ``create_app(settings)`` wires settings, database and routers into a FastAPI app.

Nothing global: every app owns its engine and session factory (on ``app.state``), so tests and
``drlaas up`` can build several apps in one process.
"""

from __future__ import annotations

import datetime as dt
import logging
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager

from fastapi import FastAPI
from starlette.concurrency import run_in_threadpool

from backend.api.errors import install_error_handlers
from backend.api.routes import api_router
from backend.api.version import VERSION
from backend.db import make_engine, make_sessionmaker, upgrade, utcnow
from backend.settings import Settings, load_settings

API_PREFIX = "/api"
log = logging.getLogger(__name__)

OPENAPI_TAGS = [
    {"name": "health", "description": "Liveness and which backend each service uses."},
    {
        "name": "auth",
        "description": "Sign in with an Ethereum key (EIP-4361 message + personal_sign) for a "
        "short-lived bearer token; a request can only act as the address that signed.",
    },
]


def create_app(
    settings: Settings | None = None,
    *,
    clock: Callable[[], dt.datetime] = utcnow,
    chain_id: int | None = None,
) -> FastAPI:
    """Build the gateway.

    ``clock`` is the source of "now" for sign-in expiry (tests move it); ``chain_id`` overrides
    the one from settings (the chain wiring sets it from the node it connects to).
    """
    settings = settings or load_settings()
    engine = make_engine(settings.database_url)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if settings.migrate_on_start:
            await run_in_threadpool(upgrade, engine)
        # Kinds only: URLs may carry credentials (postgresql://user:password@...).
        log.info(
            "gateway up (%s): chain=%s ipfs=%s broker=%s database=%s",
            settings.mode,
            settings.chain_service.kind,
            settings.ipfs_service.kind,
            settings.broker_service.kind,
            settings.database_url.split(":", 1)[0],
        )
        yield
        engine.dispose()

    app = FastAPI(
        title="DRLaaS gateway",
        summary="Crowdsourced multi-agent DRL training on a consortium chain",
        version=VERSION,
        openapi_tags=OPENAPI_TAGS,
        lifespan=lifespan,
        openapi_url=f"{API_PREFIX}/openapi.json",
        docs_url=f"{API_PREFIX}/docs",
        redoc_url=None,
    )
    app.state.settings = settings
    app.state.engine = engine
    app.state.sessions = make_sessionmaker(engine)
    app.state.clock = clock
    app.state.chain_id = chain_id if chain_id is not None else settings.effective_chain_id
    install_error_handlers(app)
    app.include_router(api_router, prefix=API_PREFIX)
    return app
