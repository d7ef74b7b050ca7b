"""``POST /rpc``: the embedded chain as a JSON-RPC endpoint (``Chain.rpc(<gateway>/rpc)``).

Mounted outside ``/api`` (it speaks JSON-RPC, not the REST error shapes). Only served when
the gateway hosts the embedded chain; with a real node clients talk to the node directly.
"""

from __future__ import annotations

import json
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field
from starlette.concurrency import run_in_threadpool

from backend.api.client_key import client_key
from backend.api.deps import LOOPBACK, ChainDep, CurrentUser, is_loopback
from backend.api.errors import RAW_BODY, RuleError, rule_responses
from backend.api.slots import ClientSlots
from backend.services.faucet import Faucet
from backend.services.rpc import INVALID_REQUEST, MAX_BATCH, METHODS, UNMETERED, EmbeddedRpc

router = APIRouter(tags=["rpc"])


CROSS_SITE = "browser-on-loopback"
"""The budget key of loopback requests that a web page made (another site's ``Origin``, or a
``Host`` that is not this machine: DNS rebinding): they are metered, unlike this machine's
own workers and CLI."""

_REQUEST = {
    "type": "object",
    "properties": {
        "jsonrpc": {"const": "2.0"},
        "method": {"enum": sorted(METHODS), "description": "the methods served here"},
        "params": {
            "type": "array",
            "maxItems": max(most for _, most in METHODS.values()),
            "description": "positional parameters (how many depends on the method)",
        },
        "id": {"type": ["string", "integer", "null"]},
    },
    "required": ["jsonrpc", "method"],
}
_RESPONSE = {
    "type": "object",
    "properties": {
        "jsonrpc": {"const": "2.0"},
        "id": {"description": "the request's id, echoed (null when the request was unreadable)"},
        "result": {},
        "error": {
            "type": "object",
            "properties": {
                "code": {"type": "integer"},
                "message": {"type": "string"},
                "data": {},
            },
            "required": ["code", "message"],
        },
    },
    "required": ["jsonrpc", "id"],
    "oneOf": [{"required": ["result"]}, {"required": ["error"]}],
}


@router.post(
    "/rpc",
    summary="JSON-RPC 2.0 of the embedded chain",
    description="A request object or a batch of 1..50. As JSON-RPC 2.0 specifies, every answer "
    "is HTTP 200, failures included: a malformed or unknown request is a response object with "
    "an ``error`` (-32700 parse error, -32600 invalid request, -32601 method not found, -32602 "
    "invalid params, 3 execution reverted).",
    response_model=None,
    responses={
        200: {
            "description": "JSON-RPC response(s): a result or an error each",
            "content": {
                "application/json": {
                    "schema": {
                        "anyOf": [
                            _RESPONSE,
                            {"type": "array", "items": _RESPONSE, "minItems": 1},
                        ]
                    }
                }
            },
        },
        **rule_responses(404, 415, 429),
    },
    openapi_extra={
        RAW_BODY: True,  # parse errors are JSON-RPC answers (-32700), not FastAPI's 400
        "requestBody": {
            "required": True,
            "content": {
                "application/json": {
                    "schema": {
                        "anyOf": [
                            _REQUEST,
                            {
                                "type": "array",
                                "items": _REQUEST,
                                "minItems": 1,
                                "maxItems": MAX_BATCH,
                            },
                        ]
                    }
                }
            },
        },
    },
)
async def rpc(request: Request) -> JSONResponse:
    server: EmbeddedRpc | None = getattr(request.app.state, "rpc", None)
    if server is None:
        raise RuleError(404, "rpc_not_embedded", "JSON-RPC is served only for the embedded chain")
    media = request.headers.get("content-type", "").split(";", 1)[0].strip().lower()
    if media != "application/json":
        # a web page may send text/plain across sites without asking (no CORS preflight);
        # application/json needs the preflight this gateway never grants
        raise RuleError(415, "rpc_content_type", "JSON-RPC requests must be sent as "
                        f"Content-Type: application/json, not {media or 'none'!r}")
    body = await request.body()  # size, depth, digits and UTF-8 bounded (backend.api.limits)
    try:
        payload: Any = json.loads(body)
    except (ValueError, RecursionError):  # JSONDecodeError, UnicodeDecodeError; and past a
        # bound the limits did not see (4,300 digits, the parser's depth): a parse error too
        return JSONResponse(
            {"jsonrpc": "2.0", "id": None, "error": {"code": -32700, "message": "parse error"}}
        )
    if not isinstance(payload, dict | list):
        return JSONResponse(
            {
                "jsonrpc": "2.0",
                "id": None,
                "error": {"code": INVALID_REQUEST, "message": "invalid request"},
            }
        )
    client = client_key(request)  # a remote IPv6 client is its /64: one budget, not 2^64
    if client in LOOPBACK and not is_loopback(request):
        client = CROSS_SITE  # a web page in a browser here: metered like a remote client
    if client in UNMETERED:
        return JSONResponse(await run_in_threadpool(server.handle, payload, client))
    slots: ClientSlots = request.app.state.rpc_slots
    if slots.take(client) is not None:
        raise RuleError(429, "rpc_busy_per_client", f"at most {slots.per_client} JSON-RPC "
                        "requests at once per client; wait for one to finish",
                        headers={"Retry-After": "1"})
    try:
        return JSONResponse(await run_in_threadpool(server.handle, payload, client))
    finally:
        slots.release(client)


contracts_router = APIRouter(prefix="/chain", tags=["rpc"])


class ContractsPublic(BaseModel):
    """What another process needs to attach (DRLAAS_CONTRACTS format plus the RPC URL)."""

    UsersManager: str
    TasksManager: str
    ModelsManager: str
    admin: str
    deploy_block: int
    chain_id: int
    rpc: str | None = Field(description="JSON-RPC URL path of the embedded chain, if served")


@contracts_router.get("/contracts", response_model=ContractsPublic, responses=rule_responses(503))
def contracts(chain: ChainDep, request: Request) -> ContractsPublic:
    """Addresses of the deployed UMC/TMC/MMC: ``Chain.rpc(<gateway>/rpc)`` + these = attached."""
    served = getattr(request.app.state, "rpc", None) is not None
    return ContractsPublic(**chain.addresses(), rpc="/rpc" if served else None)


class FaucetPublic(BaseModel):
    address: str
    balance_wei: str
    tx_hash: str | None = Field(description="the top-up transaction; null if none was needed")


@contracts_router.post(
    "/faucet", response_model=FaucetPublic, responses=rule_responses(401, 404, 429)
)
def faucet(user: CurrentUser, request: Request) -> FaucetPublic:
    """Embedded demo chain only (development mode): top the caller up to pay gas, 10 ETH when
    it holds less than 1 ETH. Rate-limited per address, per client (IPv4 address or IPv6
    network) and overall (429 + Retry-After), a few top-ups per address in all;
    answers 404 ``faucet_disabled`` anywhere else."""
    service: Faucet | None = getattr(request.app.state, "faucet", None)
    if service is None:
        raise RuleError(404, "faucet_disabled", "the faucet exists only on the embedded demo chain")
    client = client_key(request) if request.client else None  # None: counted for no client
    done = service.top_up(user.address, client)  # FaucetLimited: a domain error, 429 + Retry-After
    return FaucetPublic(
        address=done.address, balance_wei=str(done.balance_wei), tx_hash=done.tx_hash
    )
