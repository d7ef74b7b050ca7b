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

from backend.api.deps import ChainDep, CurrentUser, SettingsDep
from backend.api.errors import RuleError, rule_responses
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


FAUCET_WEI = 10 * 10**18
FAUCET_THRESHOLD_WEI = 10**18


class FaucetPublic(BaseModel):
    address: str
    balance_wei: str
    tx_hash: str | None


@contracts_router.post(
    "/faucet", response_model=FaucetPublic, responses=rule_responses(401, 403, 503)
)
def faucet(
    user: CurrentUser, chain: ChainDep, settings: SettingsDep, request: Request
) -> FaucetPublic:
    """Embedded development chain only: top the caller up to pay gas (eth-tester charges the
    base fee, and refuses even eth_call from an account that could not pay it). Sends
    10 ETH from the admin account when the caller holds less than 1 ETH."""
    if getattr(request.app.state, "rpc", None) is None or not settings.demo_keys_allowed:
        raise RuleError(403, "faucet_disabled", "the faucet exists only on the embedded dev chain")
    w3 = chain.chain.w3
    tx_hash = None
    with chain.lock:
        if w3.eth.get_balance(user.address) < FAUCET_THRESHOLD_WEI:  # type: ignore[arg-type]
            admin = chain.chain._keys[chain.platform.admin]  # type: ignore[index]
            base = w3.eth.get_block("latest").get("baseFeePerGas", 0) or 0
            tx = {
                "to": user.address,
                "value": FAUCET_WEI,
                "gas": 21_000,
                "chainId": chain.chain.chain_id,
                "nonce": w3.eth.get_transaction_count(admin.address, "pending"),
                "maxFeePerGas": 2 * base,
                "maxPriorityFeePerGas": 0,
            }
            signed = admin.sign_transaction(tx)  # type: ignore[arg-type]
            sent = w3.eth.send_raw_transaction(signed.raw_transaction)
            w3.eth.wait_for_transaction_receipt(sent)
            tx_hash = "0x" + bytes(sent).hex()
        balance = w3.eth.get_balance(user.address)  # type: ignore[arg-type]
    return FaucetPublic(address=user.address, balance_wei=str(balance), tx_hash=tx_hash)
