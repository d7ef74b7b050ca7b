"""``GET /api/blocks/{cid}``: one raw block of the content store, so a client on another machine
(or with no access to the gateway's embedded store) can fetch any content by CID, like an IPFS
trustless gateway: it rebuilds the file from blocks and verifies each one against its CID, so
it trusts neither the gateway nor the network. ``drlaas model pull`` / ``task pull`` use it.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Annotated

from fastapi import APIRouter, Path, Request
from fastapi.responses import Response

from backend.api.conditional import none_match, not_modified
from backend.api.deps import StoreDep
from backend.api.errors import RuleError, rule_responses
from backend.schemas.common import CID_LENGTH, CID_PATTERN
from backend.store import (
    CHUNK_SIZE,
    CIDMismatch,
    ContentTooLarge,
    FindTimeout,
    InvalidCID,
    NotFound,
)

router = APIRouter(prefix="/blocks", tags=["models"])

#: A block is a leaf chunk or a node of at most MAX_LINKS links: far below this bound.
MAX_BLOCK_BYTES = 4 * CHUNK_SIZE
CidPath = Annotated[
    str,
    Path(
        min_length=CID_LENGTH,
        max_length=CID_LENGTH,
        pattern=CID_PATTERN,
        description="CIDv1 of the block (sha2-256, raw or dag-pb, base32 ``b...``)",
    ),
]
RAW_BLOCK = "application/vnd.ipld.raw"


@contextmanager
def _store_errors(cid: str) -> Iterator[None]:
    """The store's failures on block ``cid`` as the gateway's rule errors."""
    try:
        yield
    except InvalidCID as exc:
        raise RuleError(422, "invalid_cid", f"{cid!r} is not a CID: {exc}") from None
    except FindTimeout as exc:  # the node gave up looking: not "absent", worth a retry
        raise RuleError(
            504, "content_find_timeout", str(exc), headers={"Retry-After": "30"}
        ) from None
    except NotFound:
        raise RuleError(404, "content_not_found", f"the store does not hold block {cid}") from None
    except (CIDMismatch, ContentTooLarge) as exc:
        raise RuleError(502, "content_corrupt", f"block {cid} failed verification: {exc}") from None


@router.get(
    "/{cid}",
    response_class=Response,
    responses={
        200: {"content": {RAW_BLOCK: {}}},
        304: {"description": "If-None-Match names this block's ETag (its CID): not sent again"},
        **rule_responses(404, 422, 502, 504),
    },
)
def get_block(cid: CidPath, request: Request, store: StoreDep) -> Response:
    """The raw bytes of block ``cid`` (verified here, and again by the reader); 304 when the
    client already holds them (``If-None-Match``): a CID's content never changes."""
    headers = {"ETag": f'"{cid}"', "Cache-Control": "public, max-age=31536000, immutable"}
    if none_match(request, headers["ETag"]):
        with _store_errors(cid):
            held = store.has(cid)
        if held:  # else the 404 a GET would get (a precondition applies to a 2xx only)
            return not_modified(headers)
    with _store_errors(cid):
        block = store.get_block(cid, max_bytes=MAX_BLOCK_BYTES)
    return Response(block, media_type=RAW_BLOCK, headers=headers)
