"""App factory: ``create_app(settings)`` wires settings, database, chain, content store, indexer
and routers into a FastAPI app.

Nothing global: every app owns its engine, session factory, chain service, store and indexer
(on ``app.state``), so tests and ``drlaas up`` can build several apps in one process. At start
(lifespan) the gateway migrates the database, connects the chain (embedded: deploys the
platform and serves it at ``POST /rpc``), opens the content store and starts the indexer
thread (docs/platform.md, "Processes").
"""

from __future__ import annotations

import datetime as dt
import logging
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager

from fastapi import Depends, FastAPI, Request
from fastapi.responses import HTMLResponse, JSONResponse
from starlette.concurrency import run_in_threadpool

from backend.api.cards import OutcomeCards
from backend.api.deps import require_metrics_token
from backend.api.docs_page import docs_page
from backend.api.errors import document_shared_responses, install_error_handlers
from backend.api.frontend import mount_docs_redirects, mount_frontend
from backend.api.head import HeadAsGet
from backend.api.limits import BodyLimits
from backend.api.pagecache import PageCache
from backend.api.pending_specs import PendingSpecs
from backend.api.relative_redirects import RelativeRedirects
from backend.api.routes import api_router, blocks, local, models, rpc, tasks, tx, users, workers
from backend.api.security_headers import SecurityHeaders
from backend.api.shedding import LoadShedder
from backend.api.slots import ClientSlots
from backend.api.version import VERSION
from backend.db import make_engine, make_sessionmaker, upgrade, utcnow
from backend.db.engine import pool_options
from backend.indexer import Indexer, IndexerThread, OfferHook
from backend.observability.logs import configure_logging
from backend.observability.metrics import install_metrics, instrument_web3
from backend.services.chain import ChainService, SignLocally
from backend.services.faucet import Faucet
from backend.services.rpc import EmbeddedRpc
from backend.services.rpc_budget import GasBudget
from backend.settings import Settings, load_settings
from backend.store import make_store

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
# Routers of the resources (users, workers, tasks, models, tx, rpc) tag their operations; their
# descriptions are not listed here because tests/backend/test_api.py pins this list.
INDEXER_INTERVAL_S = 1.0


def create_app(
    settings: Settings | None = None,
    *,
    clock: Callable[[], dt.datetime] = utcnow,
    chain_id: int | None = None,
    chain: ChainService | bool | None = None,
    on_offer: OfferHook | None = None,
    indexer_interval: float | None = INDEXER_INTERVAL_S,
) -> FastAPI:
    """Build the gateway.

    ``clock`` is the source of "now" for sign-in expiry (tests move it); ``chain_id`` overrides
    the one from settings (the chain wiring sets it from the node it connects to).
    ``chain``: a :class:`ChainService` to use (tests share one), ``None`` to connect from
    settings at start, ``False`` for no chain (auth and health only). ``on_offer`` is the
    indexer's hook for TaskOffered (the worker-daemon wiring enqueues Celery jobs with it);
    ``indexer_interval=None`` runs no indexer thread (writes still index synchronously).
    """
    settings = settings or load_settings()
    if settings.log_format == "json":
        configure_logging("json")  # DRLAAS_LOG_FORMAT; text leaves the host's logging alone
    engine = make_engine(settings.database_url, **pool_options(settings))

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if settings.migrate_on_start:
            await run_in_threadpool(upgrade, engine)
        thread = await run_in_threadpool(
            _start_services, app, settings, chain, on_offer, indexer_interval
        )
        # Kinds only: URLs may carry credentials (postgresql://user:password@...).
        log.info(
            "gateway up (%s): chain=%s ipfs=%s broker=%s database=%s",
            settings.mode,
            settings.chain_service.kind,
            settings.ipfs_service.kind,
            settings.broker_service.kind,
            settings.database_url.split(":", 1)[0],
        )
        try:
            yield
        finally:
            if thread is not None:
                await run_in_threadpool(thread.stop)
            store = getattr(app.state, "store", None)
            if store is not None:
                store.close()
            if chain is None and app.state.chain is not None:  # ours: release its file
                app.state.chain.chain.close()
            engine.dispose()

    app = FastAPI(
        title="DRLaaS gateway",
        summary="Crowdsourced multi-agent DRL training on a consortium chain",
        version=VERSION,
        openapi_tags=OPENAPI_TAGS,
        lifespan=lifespan,
        openapi_url=f"{API_PREFIX}/openapi.json",
        docs_url=None,  # backend.api.docs_page: pinned, integrity-checked, under a policy
        redoc_url=None,
    )

    @app.get(f"{API_PREFIX}/docs", include_in_schema=False)
    def api_docs() -> HTMLResponse:
        return docs_page(f"{API_PREFIX}/openapi.json", f"{app.title} - API docs")

    app.state.settings = settings
    app.state.engine = engine
    app.state.sessions = make_sessionmaker(engine)
    app.state.clock = clock
    app.state.chain_id = chain_id if chain_id is not None else settings.effective_chain_id
    app.state.chain = None
    app.state.indexer = None
    app.state.rpc = None
    app.state.faucet = None
    app.state.store = None
    app.state.page_cache = PageCache()  # list pages while the index stands still
    app.state.outcome_cards = OutcomeCards()  # outcome cards the task page read (by CID)
    # requests reading the store (a slow node) and streamed downloads (a slow client) at once
    app.state.store_reads = ClientSlots(
        settings.max_store_reads, settings.max_store_reads_per_client
    )
    app.state.download_pool = ClientSlots(settings.max_downloads, settings.max_downloads_per_client)
    # /rpc requests of remote clients at once (four parallel 500-block log reads held the lock
    # 37 s in the audit); the overall bound is the load shedder's
    app.state.rpc_slots = ClientSlots(10_000, settings.rpc_requests_per_client)
    app.state.nonce_budget = GasBudget(settings.auth_nonces_per_minute)  # one per sign-in msg
    app.state.pending_specs = PendingSpecs()  # specs stored for addTasks not relayed yet
    install_error_handlers(app)
    # added later = further out. A request counts as in flight once its body is read: bodies
    # sent slowly (each bounded in size and time by BodyLimits) never hold the shedder's
    # slots, so a few idle connections cannot answer everyone else 503; metrics see the 503s
    app.add_middleware(
        LoadShedder, limit=settings.max_in_flight, retry_after=settings.retry_after_s
    )
    app.add_middleware(
        BodyLimits,
        max_bytes=settings.max_request_bytes,
        max_depth=settings.max_json_depth,
        timeout_s=settings.body_timeout_s,
    )
    # GET /metrics, HTTP latency and errors (Prometheus), behind DRLAAS_METRICS_TOKEN if set
    install_metrics(app, settings, guards=[Depends(require_metrics_token)])
    app.add_middleware(RelativeRedirects)  # the router's slash redirects name no Host
    app.add_middleware(HeadAsGet)  # HEAD of every GET resource: its headers, no body
    app.add_middleware(SecurityHeaders)  # outermost: the shedder's and limits' answers too

    @app.exception_handler(SignLocally)
    async def _sign_locally(_: Request, exc: SignLocally) -> JSONResponse:
        return JSONResponse(
            status_code=409,
            content={
                "detail": {
                    "rule": "sign_locally",
                    "msg": f"the gateway holds no key for {exc.sender}: sign 'tx' "
                    f"({exc.description}) locally and POST it as {{'raw': '0x..'}} to /api/tx"
                    + (", then send this request again" if exc.then == "repeat" else ""),
                    "tx": exc.tx,
                    **({"then": exc.then} if exc.then else {}),
                }
            },
        )

    app.include_router(api_router, prefix=API_PREFIX)  # health, auth
    for router in (
        users.router,
        workers.router,
        tasks.router,
        models.router,
        tx.router,
        rpc.contracts_router,
        blocks.router,
        local.router,
    ):
        app.include_router(router, prefix=API_PREFIX)
    app.include_router(rpc.router)  # JSON-RPC at /rpc, outside /api
    mount_docs_redirects(app)  # /docs, /redoc -> /api/docs (the UI would answer "not found")
    mount_frontend(app)  # after every router: the mount matches any remaining path
    document_shared_responses(app)  # 400/413/422/503 of the layers in front of the routes
    return app


def _start_services(
    app: FastAPI,
    settings: Settings,
    chain: ChainService | bool | None,
    on_offer: OfferHook | None,
    interval: float | None,
) -> IndexerThread | None:
    """Chain, store, JSON-RPC server and indexer (see the module docstring)."""
    app.state.store = make_store(
        settings.ipfs, default_dir=settings.data_dir / "ipfs", max_size=settings.max_upload_bytes
    )
    if chain is False:
        return None
    if isinstance(chain, ChainService):
        service = chain
    elif settings.chain_service.embedded:
        service = ChainService.embedded(settings)  # failing here (stale artifacts) stops start-up
    else:
        try:
            service = ChainService.rpc(settings)
        except (
            Exception
        ) as exc:  # node down or no DRLAAS_CONTRACTS: serve auth/health, 503 the rest
            log.error(
                "gateway: chain %s unavailable, chain endpoints answer 503: %s", settings.chain, exc
            )
            return None
    app.state.chain = service
    instrument_web3(service.chain.w3, app.state.metrics.chain_latency)
    if app.state.chain_id is None:
        app.state.chain_id = service.chain.chain_id
    if service.chain.kind == "embedded":
        app.state.rpc = EmbeddedRpc(
            service.chain,
            service.lock,
            gas_cap=settings.rpc_gas_cap,
            budget=GasBudget(settings.rpc_gas_per_minute),
            total_budget=GasBudget(settings.rpc_gas_per_minute_total),  # all clients together
            targets=frozenset(h.address for h in service.platform.contracts),
        )
        if settings.demo_keys_allowed:  # the faucet: embedded demo chain only
            app.state.faucet = Faucet(
                service,
                interval_s=settings.faucet_interval_s,
                per_minute=settings.faucet_per_minute,
                per_client_per_minute=settings.faucet_per_client_per_minute,
                max_per_address=settings.faucet_max_per_address,
            )
    indexer = Indexer(
        service,
        app.state.sessions,
        confirmations=0 if service.chain.kind == "embedded" else settings.confirmations,
        on_offer=on_offer,
        store=app.state.store,
    )
    app.state.indexer = indexer
    if interval is None:
        return None
    thread = IndexerThread(indexer, interval)
    thread.start()
    return thread
