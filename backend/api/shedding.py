"""Load shedding: at most ``limit`` HTTP requests in flight; the next one is answered at once
with 503 + Retry-After instead of queueing until something times out (docs/platform.md,
"Overload").

A pure ASGI middleware (no per-request task or thread): the counter lives on the event loop,
where every ASGI call starts, so it needs no lock. A request counts until its response starts
(or until it returns, when it never starts one): the body that follows is only waiting on the
client, and a client that reads slowly or not at all must not hold a slot meanwhile (a few
stalled downloads would answer everyone else 503). Streamed downloads are bounded on their own:
per client and overall, and cut when their client reads nothing for a while
(``backend.api.routes.models``).
"""

from __future__ import annotations

import json
from typing import Any

Scope = dict[str, Any]


class LoadShedder:
    """ASGI middleware: ``limit`` requests in flight at most, then 503 ``overloaded``."""

    def __init__(self, app: Any, limit: int, retry_after: int) -> None:
        if limit < 1:
            raise ValueError(f"limit must be >= 1, got {limit}")
        self.app = app
        self.limit = limit
        self.in_flight = 0
        self.shed = 0  # requests answered 503 since start (for metrics and tests)
        self._body = json.dumps(
            {
                "detail": {
                    "rule": "overloaded",
                    "msg": f"the gateway is at its limit of {limit} requests in flight; "
                    f"retry after {retry_after} s",
                }
            }
        ).encode()
        self._headers = [
            (b"content-type", b"application/json"),
            (b"content-length", str(len(self._body)).encode()),
            (b"retry-after", str(retry_after).encode()),
        ]

    async def __call__(self, scope: Scope, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        if self.in_flight >= self.limit:
            self.shed += 1
            await send({"type": "http.response.start", "status": 503, "headers": self._headers})
            await send({"type": "http.response.body", "body": self._body})
            return
        self.in_flight += 1
        held = True

        def release() -> None:
            nonlocal held
            if held:
                held = False
                self.in_flight -= 1

        async def send_releasing(message: dict[str, Any]) -> None:
            if message["type"] == "http.response.start":
                release()  # what remains is sending the body: the client's pace, not ours
            await send(message)

        try:
            await self.app(scope, receive, send_releasing)
        finally:
            release()
