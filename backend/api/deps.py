"""Annotated dependencies, injected per request (never module globals): ``SettingsDep``,
``SessionDep``, ``ClockDep``, ``ChainIdDep``, ``CurrentUser``, and the platform services
``ChainDep``, ``IndexerDep``, ``StoreDep``.

The app factory puts the settings, session factory, clock and chain id on ``app.state``; tests
build their own app, so each test has its own database."""

from __future__ import annotations

import datetime as dt
import hmac
from collections.abc import AsyncIterator, Callable, Iterator
from typing import Annotated
from urllib.parse import urlsplit

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from backend.api.client_key import client_key
from backend.api.errors import RuleError
from backend.api.slots import ClientSlots
from backend.auth import User, decode_token
from backend.indexer import Indexer
from backend.services.chain import ChainService
from backend.services.rpc import UNMETERED
from backend.services.rpc_budget import GasMeter
from backend.settings import Settings
from backend.store import ContentStore


def get_settings(request: Request) -> Settings:
    return request.app.state.settings  # type: ignore[no-any-return]


SettingsDep = Annotated[Settings, Depends(get_settings)]


def get_session(request: Request) -> Iterator[Session]:
    """One session per request; rolled back (by close) unless the route committed."""
    with request.app.state.sessions() as session:
        yield session


SessionDep = Annotated[Session, Depends(get_session)]


def get_now(request: Request) -> dt.datetime:
    clock: Callable[[], dt.datetime] = request.app.state.clock
    return clock()


ClockDep = Annotated[dt.datetime, Depends(get_now)]
"""The current UTC time from the app's clock (tests move it to check expiry)."""


def get_chain_id(request: Request) -> int:
    chain_id: int | None = request.app.state.chain_id
    if chain_id is None:
        raise RuleError(
            503,
            "chain_id_unknown",
            "the gateway has not learnt the chain id yet (set DRLAAS_CHAIN_ID or wait for the "
            "chain connection)",
        )
    return chain_id


ChainIdDep = Annotated[int, Depends(get_chain_id)]

_bearer = HTTPBearer(
    auto_error=False,
    description="Access token from POST /api/auth/token (signed EIP-4361 message).",
)


def get_current_user(
    settings: SettingsDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> User:
    if credentials is None:
        raise RuleError(
            401,
            "auth_required",
            "send 'Authorization: Bearer <token>' (token from POST /api/auth/token)",
            headers={"WWW-Authenticate": 'Bearer realm="drlaas"'},
        )
    return User(address=decode_token(credentials.credentials, settings=settings))


CurrentUser = Annotated[User, Depends(get_current_user)]


def require_metrics_token(request: Request, settings: SettingsDep) -> None:
    """``GET /metrics`` with ``DRLAAS_METRICS_TOKEN`` set: 401 unless the request sends it as
    a bearer token (the whole header compared in constant time)."""
    want = settings.metrics_token
    if want is None:
        return
    sent = request.headers.get("authorization", "").encode()
    if not hmac.compare_digest(sent, b"Bearer " + want.get_secret_value().encode()):
        raise RuleError(
            401,
            "metrics_token_required",
            "send 'Authorization: Bearer <DRLAAS_METRICS_TOKEN>' to read /metrics",
            headers={"WWW-Authenticate": 'Bearer realm="drlaas-metrics"'},
        )


# -- platform services (set by create_app's lifespan; absent when the chain is disabled) --------
def get_chain(request: Request) -> ChainService:
    """The chain service, acting for this request's client: on the embedded chain a remote
    client's writes draw the executions they run under the chain lock from its ``/rpc`` gas
    budget (``ChainService.meter``); loopback clients are not metered, as on ``/rpc``."""
    service: ChainService | None = getattr(request.app.state, "chain", None)
    if service is None:
        raise RuleError(503, "chain_unavailable", "the gateway is not connected to a chain")
    rpc = getattr(request.app.state, "rpc", None)
    client = client_key(request)
    if rpc is None or client in UNMETERED:
        return service
    return service.for_client(GasMeter(rpc.joint_budget(), client, rpc.gas_cap))


ChainDep = Annotated[ChainService, Depends(get_chain)]


def get_indexer(request: Request) -> Indexer | None:
    return getattr(request.app.state, "indexer", None)


IndexerDep = Annotated[Indexer | None, Depends(get_indexer)]


async def get_store(request: Request) -> AsyncIterator[ContentStore]:
    """The content store, holding one of the store-read slots (``app.state.store_reads``,
    ``max_store_reads`` overall, ``max_store_reads_per_client`` per client key) until
    the route returns: a read of content the node cannot find waits its find timeout in one
    of the threads every sync route shares. Past a bound: 429 ``store_reads_per_client`` /
    503 ``store_reads_busy`` at once, with Retry-After. An async dependency: taking and
    giving back a slot never waits for a thread of the pool the slots protect."""
    store: ContentStore | None = getattr(request.app.state, "store", None)
    if store is None:
        raise RuleError(503, "store_unavailable", "the gateway has no content store")
    reads: ClientSlots = request.app.state.store_reads
    retry = {"Retry-After": str(request.app.state.settings.retry_after_s)}
    client = client_key(request)
    full = reads.take(client)
    if full == "client":
        raise RuleError(429, "store_reads_per_client", f"at most {reads.per_client} requests "
                        "reading the content store at once per client "
                        "(max_store_reads_per_client); wait for one to finish", headers=retry)
    if full == "total":
        raise RuleError(503, "store_reads_busy", f"the gateway is at its limit of {reads.limit} "
                        "requests reading the content store at once (max_store_reads); retry "
                        f"after {retry['Retry-After']} s", headers=retry)
    try:
        yield store
    finally:
        reads.release(client)


StoreDep = Annotated[ContentStore, Depends(get_store)]


LOOPBACK = frozenset({"127.0.0.1", "::1", "localhost"})


def is_loopback(request: Request) -> bool:
    """The request comes from this machine and from no web page of another site (what
    development-only conveniences are limited to: ``drlaas up --host 0.0.0.0`` must not hand
    them to the network). A browser on this machine is a loopback client for every site it
    visits, so the peer address alone is not enough: after DNS rebinding a page of
    ``attacker.example`` reaches this gateway with its own name in ``Host``, and a page that
    posts across sites sends its ``Origin``. Both must name this machine too."""
    if (request.client.host if request.client else "") not in LOOPBACK:
        return False
    if _hostname(request.headers.get("host", "")) not in LOOPBACK:
        return False
    origin = request.headers.get("origin")
    if origin is None:
        return True
    try:
        netloc = urlsplit(origin).netloc
    except ValueError:  # "http://[": no browser sends it, so no page of this machine did
        return False
    return _hostname(netloc) in LOOPBACK


def _hostname(authority: str) -> str:
    """``host[:port]`` or ``[v6][:port]`` -> the host, lower case, without brackets."""
    authority = authority.strip().lower()
    if authority.startswith("["):
        return authority[1:].split("]", 1)[0]
    return authority.rsplit(":", 1)[0] if authority.count(":") == 1 else authority
