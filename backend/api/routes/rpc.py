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

from backend.api.deps import ChainDep, CurrentUser
from backend.api.errors import RuleError, rule_responses
from backend.services.faucet import Faucet
from backend.services.rpc import INVALID_REQUEST, EmbeddedRpc

router = APIRouter(tags=["rpc"])


@router.post(
    "/rpc",
    summary="JSON-RPC 2.0 of the embedded chain",
    response_model=None,
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {"application/json": {"schema": {"type": ["object", "array"]}}},
        }
    },
)
async def rpc(request: Request) -> JSONResponse:
    server: EmbeddedRpc | None = getattr(request.app.state, "rpc", None)
    if server is None:
        raise RuleError(404, "rpc_not_embedded", "JSON-RPC is served only for the embedded chain")
    body = await request.body()  # size and depth already bounded (backend.api.limits)
    try:
        payload: Any = json.loads(body)
    except (json.JSONDecodeError, UnicodeDecodeError):
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
    return JSONResponse(await run_in_threadpool(server.handle, payload))


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
    it holds less than 1 ETH. Rate-limited per address and overall (429 + Retry-After);
    answers 404 ``faucet_disabled`` anywhere else."""
    service: Faucet | None = getattr(request.app.state, "faucet", None)
    if service is None:
        raise RuleError(404, "faucet_disabled", "the faucet exists only on the embedded demo chain")
    done = service.top_up(user.address)  # FaucetLimited: a domain error, 429 + Retry-After
    return FaucetPublic(
        address=done.address, balance_wei=str(done.balance_wei), tx_hash=done.tx_hash
    )
