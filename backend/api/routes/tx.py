"""Relay a transaction the caller signed locally (the answer to a 409 ``sign_locally``)."""

from __future__ import annotations

from fastapi import APIRouter
from pydantic import BaseModel, Field

from backend.api.deps import ChainDep, CurrentUser, IndexerDep, SettingsDep
from backend.api.errors import RuleError, rule_responses
from backend.api.writes import catch_up, receipt_public
from backend.schemas.common import WRITE_BODY, TxPublic
from backend.services.chain import TxPending

router = APIRouter(prefix="/tx", tags=["tx"])


class TxCreate(BaseModel):
    model_config = WRITE_BODY

    raw: str = Field(
        min_length=4,
        max_length=2 + 2 * 131_072,
        pattern=r"^0x(?:[0-9a-fA-F]{2})+$",
        description="signed raw transaction: 0x + whole bytes in hex (at most 128 KiB)",
    )


@router.post("", response_model=TxPublic, responses=rule_responses(401, 403, 409, 422, 503, 504))
def relay(
    body: TxCreate,
    user: CurrentUser,
    chain: ChainDep,
    indexer: IndexerDep,
    settings: SettingsDep,
) -> TxPublic:
    """Send ``raw`` if its recovered sender is the signed-in address and it calls a platform
    contract with a gas limit of at most ``DRLAAS_RPC_GAS_CAP`` (422 ``tx_gas_cap``); returns
    the mined receipt. Its nonce must be the sender's next one (409
    ``nonce_mismatch``: a gap would leave it queued, never mined); 504 ``tx_pending`` (with its
    hash) when the node took it but did not mine it in time."""
    try:
        rc = chain.relay_raw(bytes.fromhex(body.raw[2:]), user.address, settings.rpc_gas_cap)
    except TxPending as exc:  # a gateway timeout, not an overload: 504, not the 503 of its kind
        raise RuleError(504, exc.rule, exc.msg) from None
    catch_up(indexer)
    return TxPublic(**receipt_public(rc))
