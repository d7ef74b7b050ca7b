"""Helpers of the resource routers around a write: validation errors naming fields, receipts
as JSON, and read-your-writes indexing."""

from __future__ import annotations

import logging
from typing import Any, NoReturn

from fastapi.exceptions import RequestValidationError

from backend.chain.client import Receipt
from backend.indexer import Indexer
from backend.indexer.indexer import jsonable

log = logging.getLogger(__name__)


def field_error(loc: tuple[str | int, ...], msg: str, type_: str = "value_error") -> NoReturn:
    """Raise a 422 in the validation shape, ``loc`` naming the bad field."""
    raise RequestValidationError([{"loc": loc, "msg": msg, "type": type_}])


def catch_up(indexer: Indexer | None) -> None:
    """Index what a write just mined, so the caller's next GET sees it (embedded chains have
    no confirmations). A failure is logged: the write itself succeeded and the background
    indexer retries."""
    if indexer is None:
        return
    try:
        indexer.poll()
    except Exception:
        log.exception("indexer catch-up after a write failed (the indexer thread will retry)")


def receipt_public(rc: Receipt) -> dict[str, Any]:
    return {
        "tx_hash": rc.tx_hash,
        "block_number": rc.block_number,
        "status": rc.status,
        "events": [
            {"contract": e.contract, "name": e.name, "args": jsonable(e.args)} for e in rc.events
        ],
    }
