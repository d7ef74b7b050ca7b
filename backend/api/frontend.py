"""Serve the web UI (``frontend/``: plain HTML, ES modules and CSS, no build step) at ``/``.

The UI routes on the client (``/models/3``, ``/tasks/7``...), so any GET that names no file gets
``index.html`` and the browser's router takes over. Paths under ``/api`` and ``/rpc`` never fall
back: an unknown API path stays a JSON 404 from the app's error handlers.
"""

from __future__ import annotations

import os
from collections.abc import Awaitable, Callable
from pathlib import Path

from fastapi import FastAPI
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.responses import (
    FileResponse,
    JSONResponse,
    MalformedRangeHeader,
    RangeNotSatisfiable,
    RedirectResponse,
    Response,
)
from starlette.routing import Match, Mount
from starlette.staticfiles import NotModifiedResponse, StaticFiles
from starlette.types import Receive, Scope, Send

FRONTEND_DIR = Path(__file__).resolve().parents[2] / "frontend"
#: First path segments that belong to the gateway, not to the UI router.
RESERVED = ("api", "rpc")


class _UIFile(FileResponse):
    """A UI file whose ``Range`` answers follow RFC 9110 and the gateway's error shape:
    Starlette answered an unknown range unit 400 (a server MUST ignore it, 14.2) and a bad or
    unsatisfiable byte range 400/416 in plain text (every gateway error is JSON naming its
    rule, ``backend.api.errors``): now 416 ``range_invalid``/``range_not_satisfiable`` with
    the file's size, or the whole file for a unit other than bytes."""

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        asked = Headers(scope=scope).get("range")
        if asked is not None and self.stat_result is not None and self.status_code == 200:
            unit = asked.split("=", 1)[0].strip().lower()
            if unit != "bytes":  # not ours to understand: the whole file
                headers = [(k, v) for k, v in scope["headers"] if k != b"range"]
                scope = {**scope, "headers": headers}
            else:
                size = self.stat_result.st_size
                refusal = _range_refusal(asked, size)
                if refusal is not None:
                    await refusal(scope, receive, send)
                    return
        await super().__call__(scope, receive, send)


def _range_refusal(asked: str, size: int) -> Response | None:
    """The 416 for ``Range: asked`` on a file of ``size`` bytes, None when it is served."""
    shown = asked if len(asked) <= 64 else asked[:64] + "..."
    try:
        FileResponse._parse_range_header(asked, size)
    except MalformedRangeHeader as exc:
        rule, why = "range_invalid", exc.content
    except RangeNotSatisfiable:
        rule, why = "range_not_satisfiable", "a range starts at or after the end of the file"
    else:
        return None
    return JSONResponse(
        status_code=416,
        content={"detail": {"rule": rule, "msg": f"Range {shown!r}: {why} (the file is {size} "
                                                 f"bytes: bytes=0-{max(size - 1, 0)} at most)"}},
        headers={"Content-Range": f"bytes */{size}"},
    )


class SPAStaticFiles(StaticFiles):
    """StaticFiles with an ``index.html`` fallback for client-side routes."""

    def file_response(
        self,
        full_path: str | os.PathLike[str],
        stat_result: os.stat_result,
        scope: Scope,
        status_code: int = 200,
    ) -> Response:
        response = _UIFile(full_path, status_code=status_code, stat_result=stat_result)
        if self.is_not_modified(response.headers, Headers(scope=scope)):
            return NotModifiedResponse(response.headers)
        return response

    async def get_response(self, path: str, scope: Scope) -> Response:
        first = path.split("/", 1)[0]
        if first in RESERVED:
            raise HTTPException(status_code=404, detail=f"no route {scope.get('path')!r}")
        try:
            response = await super().get_response(path, scope)
        except HTTPException as exc:
            # A missing file with an extension (/app.js typo) is a real 404; a bare path is a route.
            if exc.status_code != 404 or "." in path.rsplit("/", 1)[-1]:
                raise
            response = await super().get_response("index.html", scope)
        if path in (".", "", "index.html") or response.media_type == "text/html":
            # The shell is tiny; always revalidate so a new deploy is picked up at once.
            response.headers["Cache-Control"] = "no-cache"
        return response


class _UIMount(Mount):
    """A mount at ``/`` that refuses gateway paths, so the router still answers them itself:
    405 for a wrong method on an API route, JSON 404 for an unknown one."""

    def matches(self, scope: Scope) -> tuple[Match, Scope]:
        if scope.get("type") == "http":
            first = scope.get("path", "/").lstrip("/").split("/", 1)[0]
            if first in RESERVED:
                return Match.NONE, {}
        return super().matches(scope)


#: Where people look for API documentation, and where it is.
DOCS_ALIASES = {"/docs": "/api/docs", "/redoc": "/api/docs", "/openapi.json": "/api/openapi.json"}


def mount_docs_redirects(app: FastAPI) -> None:
    """Redirect the usual documentation paths to the gateway's (under ``/api``)."""
    for alias, target in DOCS_ALIASES.items():
        app.add_api_route(alias, _redirect_to(target), methods=["GET"], include_in_schema=False)


def _redirect_to(target: str) -> Callable[[], Awaitable[RedirectResponse]]:
    async def redirect() -> RedirectResponse:  # no parameters: the target is fixed
        return RedirectResponse(target, status_code=307)

    return redirect


def mount_frontend(app: FastAPI, directory: str | Path = FRONTEND_DIR) -> None:
    """Serve ``directory`` at ``/``. Call after every router is included: the mount matches any
    path, so routes added later would be shadowed."""
    directory = Path(directory)
    if not (directory / "index.html").is_file():
        raise FileNotFoundError(f"web UI not found: {directory / 'index.html'} does not exist")
    app.router.routes.append(
        _UIMount("/", app=SPAStaticFiles(directory=directory, html=True), name="frontend")
    )
