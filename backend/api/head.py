"""``HEAD`` of every ``GET`` resource: its status and headers, without its body (RFC 9110,
9.3.2: a general-purpose server supports GET and HEAD).

FastAPI routes a ``GET`` route for ``GET`` only, so ``HEAD /api/health`` (what uptime
monitors and proxies send) and ``HEAD /api/models/{id}/download`` (a client asking a file's
size) answered 405. A ``HEAD`` request runs as the ``GET`` it names, with its headers
(``Content-Length`` included), and the body is not sent. A streamed download reads nothing
more than it needed for its headers: ``HEAD_ONLY`` in the scope tells it so
(``routes.models._Download``).
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

HEAD_ONLY = "drlaas.head_only"
"""Scope key set on a ``HEAD`` request run as ``GET``: a response may skip making its body."""


class HeadAsGet:
    """Pure ASGI middleware: ``HEAD`` runs as ``GET``; the answer's body is left out."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "HEAD":
            await self.app(scope, receive, send)
            return
        ended = False

        async def send_head(message: Message) -> None:
            nonlocal ended
            if message["type"] == "http.response.start":
                await send(message)
            elif message["type"] == "http.response.body" and not ended:
                ended = True  # one empty body ends the answer; the rest is not sent
                await send({"type": "http.response.body", "body": b"", "more_body": False})

        await self.app({**scope, "method": "GET", HEAD_ONLY: True}, receive, send_head)
