"""The gateway's two JSON error shapes, and the exception that produces the second.

* validation (422): ``{"detail": [{"loc": ["body", "address"], "msg": ..., "type": ...}]}``
* a rule that failed: ``{"detail": {"rule": "siwe_nonce_used", "msg": ...}}``

Every HTTP error, including 404/405 from routing and unexpected 500s, uses one of the two, so a
client never has to parse a bare string.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException

log = logging.getLogger(__name__)


class RuleError(Exception):
    """A request broke a named rule: answered as ``{"detail": {"rule", "msg"}}``.

    ``rule`` is a stable snake_case identifier clients can switch on; ``msg`` is for humans.
    """

    def __init__(
        self,
        status_code: int,
        rule: str,
        msg: str,
        *,
        headers: Mapping[str, str] | None = None,
    ) -> None:
        super().__init__(f"{rule}: {msg}")
        self.status_code = status_code
        self.rule = rule
        self.msg = msg
        self.headers = dict(headers or {})


class RuleFailure(BaseModel):
    rule: str
    msg: str


class RuleErrorBody(BaseModel):
    """Body of every non-validation error."""

    detail: RuleFailure


class ValidationIssue(BaseModel):
    loc: list[str | int]
    msg: str
    type: str


class ValidationErrorBody(BaseModel):
    """Body of a 422: one entry per bad field, ``loc`` naming it."""

    detail: list[ValidationIssue]


def rule_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses=`` entries documenting rule failures for ``codes``."""
    return {code: {"model": RuleErrorBody} for code in codes}


def validation_issues(errors: Sequence[Any]) -> list[dict[str, Any]]:
    # Only loc/msg/type: pydantic's "input" would echo request data (signatures, tokens).
    return [
        {
            "loc": list(e.get("loc", ())),
            "msg": str(e.get("msg", "")),
            "type": str(e.get("type", "")),
        }
        for e in errors
    ]


_HTTP_RULES = {
    400: "bad_request",
    401: "unauthorized",
    403: "forbidden",
    404: "not_found",
    405: "method_not_allowed",
    413: "payload_too_large",
    415: "unsupported_media_type",
}


DB_BUSY_RETRY_AFTER_S = 2
"""Retry-After of a 503 ``database_busy`` (every pooled connection stayed busy)."""


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(RequestValidationError)
    async def _validation(_: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse(status_code=422, content={"detail": validation_issues(exc.errors())})

    @app.exception_handler(RuleError)
    async def _rule(_: Request, exc: RuleError) -> JSONResponse:
        return JSONResponse(
            status_code=exc.status_code,
            content={"detail": {"rule": exc.rule, "msg": exc.msg}},
            headers=exc.headers or None,
        )

    @app.exception_handler(StarletteHTTPException)
    async def _http(_: Request, exc: StarletteHTTPException) -> JSONResponse:
        rule = _HTTP_RULES.get(exc.status_code, f"http_{exc.status_code}")
        return JSONResponse(
            status_code=exc.status_code,
            content={"detail": {"rule": rule, "msg": str(exc.detail)}},
            headers=getattr(exc, "headers", None),
        )

    @app.exception_handler(PoolTimeout)
    async def _pool_exhausted(request: Request, exc: PoolTimeout) -> JSONResponse:
        # Overload, not a bug: every connection stayed busy for the pool timeout.
        log.warning("database pool exhausted on %s %s: %s", request.method, request.url.path, exc)
        return JSONResponse(
            status_code=503,
            content={
                "detail": {
                    "rule": "database_busy",
                    "msg": "every database connection is busy; retry later",
                }
            },
            headers={"Retry-After": str(DB_BUSY_RETRY_AFTER_S)},
        )

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse(
            status_code=500,
            content={"detail": {"rule": "internal_error", "msg": "internal server error"}},
        )
