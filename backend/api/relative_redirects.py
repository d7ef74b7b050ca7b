"""Redirects that stay on the site the client asked: ``Location`` without a host.

Starlette's router answers ``/api/models/`` with a 307 to ``/api/models``, built as an absolute
URL from the request's ``Host`` header. A request (or a cache in front of the gateway, or a
page that made the browser send it) naming another host gets a redirect to that host: an open
redirect, and a poisoned cached answer for everyone else. A relative ``Location`` (RFC 9110
allows it) sends the client to the same path on the host it is already talking to, whatever
the header said.
"""

from __future__ import annotations

from urllib.parse import urlsplit, urlunsplit

from starlette.types import ASGIApp, Message, Receive, Scope, Send


def _request_host(scope: Scope) -> str | None:
    for name, value in scope.get("headers", ()):
        if name == b"host":
            return value.decode("latin-1").lower()
    return None


def relative_location(location: str, host: str | None) -> str:
    """``location`` without scheme and host when its host is the request's ``Host`` (what a
    redirect built from the request names); any other location unchanged."""
    parts = urlsplit(location)
    if not parts.scheme or parts.netloc.lower() != (host or ""):
        return location
    path = parts.path or "/"
    if path.startswith("//"):  # "//x" relative would name host x
        path = "/" + path.lstrip("/")
    return urlunsplit(("", "", path, parts.query, parts.fragment))


class RelativeRedirects:
    """Pure ASGI middleware: rewrites the ``Location`` of 3xx answers to a relative one."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        host = _request_host(scope)

        async def send_relative(message: Message) -> None:
            if message["type"] == "http.response.start" and 300 <= message["status"] < 400:
                message["headers"] = [
                    (name, relative_location(value.decode("latin-1"), host).encode("latin-1"))
                    if name.lower() == b"location"
                    else (name, value)
                    for name, value in message.get("headers", ())
                ]
            await send(message)

        await self.app(scope, receive, send_relative)
