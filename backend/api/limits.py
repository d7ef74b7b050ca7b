"""Request bodies are bounded before anything parses them: size (413), JSON depth and number
length (422).

A pure ASGI middleware in front of every route (``/api/*``, ``/rpc``, the sign-in nonce
endpoint): it reads the body itself, refusing it as soon as it passes ``max_bytes`` (at once
when ``Content-Length`` says so), then measures bracket nesting by scanning bytes, without
recursion, so a 100,000-deep array is refused in microseconds instead of reaching a recursive
JSON parser. A number with more digits than any field takes (a uint256 has 78) is refused by
name too: Python's parser would stop at 4,300 digits with a bare "error parsing the body".
A body that is not UTF-8 (UTF-16 or UTF-32, which Python's parser reads too) is refused first
(415 ``json_not_utf8``): the scans read bytes as UTF-8. Accepted bodies are handed on
unchanged. Refusals use the gateway's rule shape
``{"detail": {"rule", "msg"}}``.
"""

from __future__ import annotations

import asyncio
import json
import re
from typing import Any

from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

# A JSON string: quote, runs of plain bytes or escape pairs, closing quote. The closing quote is
# optional so an unterminated string still matches (to the end): the pattern never fails after
# its first byte, hence never backtracks, and the scan stays linear in the body size.
_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"?', re.DOTALL)
_OPENERS = b"[{"
_NOT_BRACKETS = bytes(b for b in range(256) if b not in b"[]{}")
MAX_NUMBER_DIGITS = 256
_LONG_DIGITS = re.compile(rb"[0-9]{%d}" % (MAX_NUMBER_DIGITS + 1))


def json_depth_exceeds(body: bytes, limit: int) -> bool:
    """True if brackets outside JSON strings nest deeper than ``limit`` (escapes honoured).

    Works on any bytes (not only valid JSON): whatever the parser would do later, nothing it is
    given is deeper than ``limit``.
    """
    if body.count(b"[") + body.count(b"{") <= limit:
        return False  # cannot nest deeper than the number of openers
    brackets = _STRING.sub(b"", body).translate(None, _NOT_BRACKETS)
    depth = 0
    for byte in brackets:
        if byte in _OPENERS:
            depth += 1
            if depth > limit:
                return True
        else:
            depth -= 1
    return False


UTF8 = ("utf-8", "utf-8-sig")


def json_encoding(body: bytes) -> str:
    """The encoding Python's JSON parser reads ``body`` in (``json.detect_encoding``: UTF-8,
    with or without its byte order mark, or UTF-16/32 from a BOM or the NULs of the first
    bytes)."""
    return json.detect_encoding(body) if body else "utf-8"


def json_number_too_long(body: bytes) -> bool:
    """True if a run of more than :data:`MAX_NUMBER_DIGITS` digits stands outside JSON strings
    (digits inside strings, hex or CIDs, are the fields' own business)."""
    return _LONG_DIGITS.search(body) is not None and (
        _LONG_DIGITS.search(_STRING.sub(b"", body)) is not None
    )


class BodyLimits:
    """ASGI middleware: refuse bodies over ``max_bytes``, nested deeper than ``max_depth``, or
    not sent in full within ``timeout_s`` (408, connection closed)."""

    def __init__(
        self, app: ASGIApp, *, max_bytes: int, max_depth: int, timeout_s: float = 10.0
    ) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.max_depth = max_depth
        self.timeout_s = timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = _content_length(scope)
        if declared is not None and declared > self.max_bytes:
            await self._too_large(scope, receive, send)
            return
        chunks: list[bytes] = []
        size = 0
        deadline = asyncio.get_running_loop().time() + self.timeout_s
        while True:
            try:
                message = await asyncio.wait_for(
                    receive(), timeout=max(deadline - asyncio.get_running_loop().time(), 0)
                )
            except TimeoutError:
                await _refuse(
                    scope,
                    receive,
                    send,
                    408,
                    "body_timeout",
                    f"request bodies must arrive within {self.timeout_s:g} s",
                    close=True,
                )
                return
            if message["type"] == "http.disconnect":
                return  # the client left; nothing to answer
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_bytes:
                await self._too_large(scope, receive, send)
                return
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        body = b"".join(chunks)
        encoding = json_encoding(body)
        if encoding not in UTF8:
            # the scans below read bytes as UTF-8: in UTF-16 an escaped quote ends the string
            # they skip (brackets and digits after it would go unseen), and Python's parser
            # would read the body all the same
            await _refuse(
                scope,
                receive,
                send,
                415,
                "json_not_utf8",
                f"request bodies are JSON in UTF-8 (RFC 8259); this one reads as {encoding}",
            )
            return
        if json_depth_exceeds(body, self.max_depth):
            await _refuse(
                scope,
                receive,
                send,
                422,
                "json_too_deep",
                f"request bodies nest at most {self.max_depth} levels of arrays/objects",
            )
            return
        if json_number_too_long(body):
            await _refuse(
                scope,
                receive,
                send,
                422,
                "json_number_too_long",
                f"numbers in request bodies have at most {MAX_NUMBER_DIGITS} digits",
            )
            return
        await self.app(scope, _replay(body, receive), send)

    async def _too_large(self, scope: Scope, receive: Receive, send: Send) -> None:
        await _refuse(
            scope,
            receive,
            send,
            413,
            "payload_too_large",
            f"request bodies are at most {self.max_bytes} bytes",
            close=True,  # the rest of the body is never read
        )


def _content_length(scope: Scope) -> int | None:
    for name, value in scope.get("headers", ()):
        if name == b"content-length":
            try:
                return int(value)
            except ValueError:
                return None  # the server rejects a malformed length itself
    return None


def _replay(body: bytes, receive: Receive) -> Receive:
    """A ``receive`` that yields the buffered body once, then defers to the real one
    (so disconnects still reach the app)."""
    sent = False

    async def replayed() -> Message:
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replayed


async def _refuse(
    scope: Scope,
    receive: Receive,
    send: Send,
    status: int,
    rule: str,
    msg: str,
    *,
    close: bool = False,
) -> None:
    content: dict[str, Any] = {"detail": {"rule": rule, "msg": msg}}
    headers = {"Connection": "close"} if close else None
    await JSONResponse(content, status_code=status, headers=headers)(scope, receive, send)
