"""Browser security headers on every response of the gateway.

The web UI shows user content (model descriptions, task specs, worker names) and serves files
from the content store; it only ever inserts that content as text (``frontend/js/dom.js``),
and these headers are the second line should a page ever slip: the browser runs no script,
style or frame that the gateway itself did not serve, never guesses a download's type (a
``.json`` someone uploaded is not run as HTML), sends no referrer to other sites and lets no
other site frame the UI (clickjacking a wallet's signature).

The API docs (``/api/docs``) set a policy of their own (``backend.api.docs_page``: Swagger UI's
pinned CDN files and its inline starter script by hash); a response's own policy is kept.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

CONTENT_SECURITY_POLICY = "; ".join(
    (
        "default-src 'self'",
        "script-src 'self'",
        "style-src 'self'",  # style attributes are set through the CSSOM (dom.js), not markup
        "img-src 'self' data: blob:",
        "connect-src 'self'",
        "object-src 'none'",
        "base-uri 'none'",
        "form-action 'self'",
        "frame-ancestors 'none'",
    )
)
"""The UI's policy: its own scripts, styles and API only; no plugins, no framing."""

HEADERS = (
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"x-frame-options", b"DENY"),
    (b"cross-origin-opener-policy", b"same-origin"),
)
"""On every response, the docs included."""



def security_headers() -> dict[str, str]:
    """The headers :class:`SecurityHeaders` adds, for answers made outside it (Starlette
    answers an unhandled exception's 500 outside every middleware)."""
    out = {k.decode(): v.decode() for k, v in HEADERS}
    out["content-security-policy"] = CONTENT_SECURITY_POLICY
    return out


class SecurityHeaders:
    """ASGI middleware (pure, so streamed downloads stay streamed) adding ``HEADERS`` and the
    ``CONTENT_SECURITY_POLICY`` to every HTTP response that does not set them itself."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        extra = [*HEADERS, (b"content-security-policy", CONTENT_SECURITY_POLICY.encode())]

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", []))
                present = {name.lower() for name, _ in headers}
                headers += [(k, v) for k, v in extra if k not in present]
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, send_with_headers)
