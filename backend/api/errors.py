"""The gateway's two JSON error shapes, and the exception that produces the second.

* validation (422): ``{"detail": [{"loc": ["body", "address"], "msg": ..., "type": ...}]}``
* a rule that failed: ``{"detail": {"rule": "siwe_nonce_used", "msg": ...}}``

Every HTTP error, including 404/405 from routing and unexpected 500s, uses one of the two, so a
client never has to parse a bare string.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, RootModel
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match, Mount

from backend import errors as domain
from backend.api.head import HEAD_ONLY
from backend.api.security_headers import security_headers
from backend.errors import DomainError
from backend.store import StoreUnavailable

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


class UnprocessableBody(RootModel[ValidationErrorBody | RuleErrorBody]):
    """Body of a 422: a validation list, or a rule the valid request broke (e.g. a limit)."""


def rule_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses=`` entries documenting rule failures for ``codes`` (a 422 may be
    either shape: field validation or a named rule)."""
    return {code: {"model": UnprocessableBody if code == 422 else RuleErrorBody} for code in codes}


SHARED_RESPONSES: dict[int, type[BaseModel]] = {
    408: RuleErrorBody,  # BodyLimits: body not sent within body_timeout_s
    413: RuleErrorBody,  # BodyLimits: body over max_request_bytes
    422: UnprocessableBody,  # BodyLimits json_too_deep (rule) or field validation (list)
    503: RuleErrorBody,  # LoadShedder: overloaded, with Retry-After
}
"""Statuses the layers in front of every route answer, whatever the route (backend.api.limits,
backend.api.shedding)."""
BODY_RESPONSES: dict[int, type[BaseModel]] = {400: RuleErrorBody}
"""Statuses of an operation that reads a JSON body: 400 ``bad_request`` when the body is not
text FastAPI can decode (e.g. invalid UTF-8; bad JSON syntax is a 422 ``json_invalid``)."""
ENCODED_BODY_RESPONSES: dict[int, type[BaseModel]] = {415: RuleErrorBody}
"""Statuses of every operation with a request body: 415 ``json_not_utf8`` when the body is
JSON in UTF-16 or UTF-32 (``backend.api.limits``: JSON between systems is UTF-8), 415
``json_content_type`` when a JSON route's body came as another type (or none)."""
RAW_BODY = "x-raw-body"
"""``openapi_extra={RAW_BODY: True}`` marks a route that reads its body itself (``POST /rpc``
answers undecodable bodies in its own protocol), so FastAPI's 400 does not apply to it."""
_METHODS = frozenset({"get", "put", "post", "delete", "patch", "head", "options", "trace"})


def document_shared_responses(app: FastAPI) -> None:
    """Declare :data:`SHARED_RESPONSES` on every operation of ``app``'s OpenAPI document and
    :data:`BODY_RESPONSES` on those with a request body, so the document lists every status a
    client can get (a route's own declaration of a code is kept; FastAPI's default 422, which
    knows only the validation list, becomes :class:`UnprocessableBody`)."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is not None:
            return app.openapi_schema
        doc = build()
        components = doc.setdefault("components", {}).setdefault("schemas", {})
        for model in {*SHARED_RESPONSES.values(), *BODY_RESPONSES.values(),
                      *ENCODED_BODY_RESPONSES.values()}:
            schema = model.model_json_schema(ref_template="#/components/schemas/{model}")
            for name, definition in schema.pop("$defs", {}).items():
                components.setdefault(name, definition)
            components.setdefault(model.__name__, schema)
        for item in doc.get("paths", {}).values():
            for method, operation in item.items():
                if method not in _METHODS:
                    continue
                responses = operation.setdefault("responses", {})
                shared = dict(SHARED_RESPONSES)
                if "requestBody" in operation:
                    shared.update(ENCODED_BODY_RESPONSES)
                if "requestBody" in operation and not operation.pop(RAW_BODY, False):
                    shared.update(BODY_RESPONSES)
                for code, model in shared.items():
                    declared = responses.get(str(code))
                    if declared is not None and not _is_fastapi_default_422(code, declared):
                        continue
                    responses[str(code)] = _response(code, model)
        return doc

    app.openapi = openapi  # type: ignore[method-assign]


def _is_fastapi_default_422(code: int, declared: dict[str, Any]) -> bool:
    schema = declared.get("content", {}).get("application/json", {}).get("schema", {})
    return code == 422 and schema.get("$ref", "").endswith("/HTTPValidationError")


def _response(code: int, model: type[BaseModel]) -> dict[str, Any]:
    return {
        "description": HTTPStatus(code).phrase,
        "content": {
            "application/json": {"schema": {"$ref": f"#/components/schemas/{model.__name__}"}}
        },
    }


MAX_ISSUE_TEXT = 1000
"""Longest ``msg`` or ``loc`` entry of a 422 (its head and tail are kept): a message that
quotes a megabyte of input must not answer with it."""
MAX_ISSUES = 50


def validation_issues(errors: Sequence[Any]) -> list[dict[str, Any]]:
    # Only loc/msg/type: pydantic's "input" would echo request data (signatures, tokens).
    return [
        {
            "loc": [p if isinstance(p, int) else _short(str(p)) for p in e.get("loc", ())],
            "msg": _short(_message(e)),
            "type": _short(str(e.get("type", ""))),
        }
        for e in list(errors)[:MAX_ISSUES]
    ]


def _is_json(content_type: str) -> bool:
    """Whether FastAPI decodes a body of ``content_type`` as JSON (``application/json`` or
    ``application/*+json``, any case, any parameters)."""
    kind = content_type.split(";", 1)[0].strip().lower()
    return kind == "application/json" or (
        kind.startswith("application/") and kind.endswith("+json")
    )


def _body_not_json(request: Request, errors: Sequence[Any]) -> str | None:
    """How the request described a body it sent in a type FastAPI does not decode as JSON
    (none, ``text/plain``, a form...), when that is why the body was refused: FastAPI then
    validates the raw bytes, and its 422 said "Input should be a valid dictionary" of a JSON
    object the client did send. None otherwise."""
    content_type = request.headers.get("content-type")
    if content_type is not None and _is_json(content_type):
        return None
    whole_body = [e for e in errors if tuple(e.get("loc", ())) == ("body",)]
    if not whole_body or any(e.get("type") == "missing" for e in whole_body):
        return None  # no body at all: "Field required" names what is wrong
    return "no Content-Type" if content_type is None else f"Content-Type: {content_type[:100]!r}"


def _message(error: Any) -> str:
    """pydantic's message, except where it describes what was not sent: an integer field given
    a JSON number like ``1e20`` says "unable to parse input string", of a string nobody sent."""
    if error.get("type") == "int_parsing_size" and isinstance(error.get("input"), float):
        return ("Input should be an integer within the field's bounds; this number is far "
                "beyond them")
    return str(error.get("msg", ""))


def _short(text: str) -> str:
    if len(text) <= MAX_ISSUE_TEXT:
        return text
    # head and tail (a message's end often names the rule), 90% of the budget in all
    head, tail = MAX_ISSUE_TEXT * 7 // 10, MAX_ISSUE_TEXT // 5
    return f"{text[:head]} ... ({len(text)} characters in all) ... {text[-tail:]}"


_HTTP_RULES = {
    400: "bad_request",
    401: "unauthorized",
    403: "forbidden",
    404: "not_found",
    405: "method_not_allowed",
    413: "payload_too_large",
    415: "unsupported_media_type",
}


DOMAIN_STATUS: dict[type[DomainError], int] = {
    domain.BadRequest: 400,
    domain.Unauthorized: 401,
    domain.PaymentRequired: 402,
    domain.Forbidden: 403,
    domain.NotFound: 404,
    domain.Conflict: 409,
    domain.TooLarge: 413,
    domain.Invalid: 422,
    domain.RateLimited: 429,
    domain.Unavailable: 503,
}
"""HTTP status of each kind of domain error (backend.errors); the body is the rule shape."""
_BEARER_CHALLENGE = {"WWW-Authenticate": 'Bearer realm="drlaas"'}


def domain_status(exc: DomainError) -> int:
    for cls in type(exc).__mro__:
        if cls in DOMAIN_STATUS:
            return DOMAIN_STATUS[cls]
    return 409


def domain_headers(exc: DomainError) -> dict[str, str]:
    headers = dict(_BEARER_CHALLENGE) if isinstance(exc, domain.Unauthorized) else {}
    if exc.retry_after is not None:
        headers["Retry-After"] = str(max(1, math.ceil(exc.retry_after)))
    return headers


_METHOD_PROBES = ("GET", "POST", "PUT", "PATCH", "DELETE")


def allowed_methods(request: Request) -> list[str]:
    """Every method the app's routes take on the request's path, HEAD with GET (``HeadAsGet``):
    the ``Allow`` of a 405 (RFC 9110, 15.5.6). Starlette named the methods of the first route
    that matched the path only, so ``PUT /api/tasks`` said ``Allow: POST`` of a path that GET
    serves as well. Each method is asked of the router as a request would be (included routers
    are resolved lazily); the UI's mount, which takes any path, says its own. Empty when no
    route matches."""
    methods: set[str] = set()
    routes = [r for r in request.app.router.routes if not isinstance(r, Mount)]
    for method in _METHOD_PROBES:
        probe = {**request.scope, "method": method}
        if any(route.matches(probe)[0] is Match.FULL for route in routes):
            methods.add(method)
    if "GET" in methods:
        methods.add("HEAD")
    return sorted(methods)


DB_BUSY_RETRY_AFTER_S = 2
"""Retry-After of a 503 ``database_busy`` (every pooled connection stayed busy)."""


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(DomainError)
    async def _domain(_: Request, exc: DomainError) -> JSONResponse:
        return JSONResponse(
            status_code=domain_status(exc),
            content={"detail": {"rule": exc.rule, "msg": exc.msg}},
            headers=domain_headers(exc) or None,
        )

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        wrong_type = _body_not_json(request, exc.errors())
        if wrong_type is not None:
            return JSONResponse(status_code=415, content={"detail": {
                "rule": "json_content_type",
                "msg": f"this route reads a JSON object: send it with Content-Type: "
                       f"application/json (the request said {wrong_type})"}})
        return JSONResponse(status_code=422, content={"detail": validation_issues(exc.errors())})

    @app.exception_handler(RuleError)
    async def _rule(_: Request, exc: RuleError) -> JSONResponse:
        return JSONResponse(
            status_code=exc.status_code,
            content={"detail": {"rule": exc.rule, "msg": exc.msg}},
            headers=exc.headers or None,
        )

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        rule = _HTTP_RULES.get(exc.status_code, f"http_{exc.status_code}")
        msg, headers = str(exc.detail), getattr(exc, "headers", None)
        allowed = allowed_methods(request) if exc.status_code == 405 else []
        if allowed:
            headers = {**(headers or {}), "Allow": ", ".join(allowed)}
            method = "HEAD" if request.scope.get(HEAD_ONLY) else request.method  # run as GET
            msg = (f"{method} is not allowed on {_short(request.url.path)}; it allows "
                   + ", ".join(allowed))
        return JSONResponse(
            status_code=exc.status_code,
            content={"detail": {"rule": rule, "msg": msg}},
            headers=headers,
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

    @app.exception_handler(StoreUnavailable)
    async def _store_down(request: Request, exc: StoreUnavailable) -> JSONResponse:
        # the node is down or slow: any route that reads the store says so, not "internal"
        log.warning("content store unavailable on %s %s: %s", request.method,
                    request.url.path, exc.reason)
        return JSONResponse(
            status_code=503,
            content={"detail": {"rule": "store_unavailable",
                                "msg": "the content store is unavailable; retry later"}},
            headers={"Retry-After": str(max(1, math.ceil(exc.retry_after)))},
        )

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse(
            status_code=500,
            content={"detail": {"rule": "internal_error", "msg": "internal server error"}},
            headers=security_headers(),  # answered outside SecurityHeaders
        )
