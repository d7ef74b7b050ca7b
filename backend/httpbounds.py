"""Bounded reading of HTTP answers from servers the client does not trust (docs/platform.md,
"Clients against hostile servers").

Every answer a client reads is bounded in bytes and in time: its body must arrive within
``deadline_s`` of its headers (the read timeout bounds each wait only, so a server dripping a
byte per timeout would otherwise hold the client for ever) and may hold at most ``max_bytes``
(a body without end would otherwise fill the memory). An error answer (non-2xx) is read up to
:data:`ERROR_BODY_BYTES` only, then reading stops: its start is enough to report it.

:func:`bounded_client` makes an ``httpx.Client`` that enforces this on every request, whether
read whole or streamed (``client.stream``): an event hook wraps each response's byte stream.
A request may carry its own byte cap and deadline in its extensions (``{MAX_BYTES: n,
DEADLINE_S: s}``; ``None``: the caller bounds the size or the time of a 2xx body itself, as
block reads do; an error body is always bounded here). :class:`Budget` is the same check for
other HTTP stacks (the chain client's ``requests`` session).

Compressed answers are refused: the clients ask for ``identity``, and a cap on compressed bytes
would not bound what decompression makes of them.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from typing import Any
from urllib.parse import urlsplit, urlunsplit

import httpx

MAX_BYTES = "drlaas.max_bytes"
"""Request extension: the byte cap of this request's 2xx body (``None``: the caller's own)."""
DEADLINE_S = "drlaas.deadline_s"
"""Request extension: the deadline of this request's 2xx body (``None``: the caller's own)."""
DEFAULT_MAX_BYTES = 8 * 2**20
"""Default cap of an answer's body (JSON API answers are far smaller)."""
ERROR_BODY_BYTES = 64 * 2**10
"""Bytes of an error answer's body that are read; the rest is not."""
DEADLINE_FACTOR = 2
"""Default deadline of a body: this many read timeouts after its headers."""


class ResponseBoundError(Exception):
    """An answer broke a bound; ``url`` names the server and the message what was exceeded."""

    def __init__(self, url: str, problem: str) -> None:
        self.url = without_userinfo(url)
        super().__init__(f"answer of {self.url} refused: {problem}")


def without_userinfo(url: str) -> str:
    """``url`` without ``user:password@`` (errors are logged)."""
    parts = urlsplit(url)
    if "@" not in parts.netloc:
        return url
    return urlunsplit(parts._replace(netloc=parts.netloc.rpartition("@")[2]))


class ResponseTooLarge(ResponseBoundError):
    """The body is larger than ``limit`` bytes (declared or while arriving)."""

    def __init__(self, url: str, limit: int, got: int | None = None) -> None:
        self.limit = limit
        size = f"declares {got} bytes" if got is not None else "goes on"
        super().__init__(url, f"its body {size}, past the cap of {limit} bytes")


class ResponseTooSlow(ResponseBoundError):
    """The body did not arrive within ``limit`` seconds of the headers."""

    def __init__(self, url: str, limit: float, got: int) -> None:
        self.limit = limit
        super().__init__(
            url, f"its body did not arrive within the deadline of {limit:g} s ({got} bytes so far)"
        )


class ResponseRefused(ResponseBoundError):
    """An answer the client does not read at all (compressed, a redirect)."""


# httpx flavours: existing ``except httpx.HTTPError`` / ``httpx.TransportError`` clauses catch
# them (a slow body is a timeout: transient; a huge one is an answer the server got wrong).
class BodyTooLarge(ResponseTooLarge, httpx.HTTPError):
    pass


class BodyTooSlow(ResponseTooSlow, httpx.ReadTimeout):
    pass


class BodyRefused(ResponseRefused, httpx.HTTPError):
    pass


class Budget:
    """Bytes and time left for one body: :meth:`declared` with its Content-Length,
    :meth:`take` with each chunk; both raise the ``ResponseBound*`` errors (or ``too_large`` /
    ``too_slow``, their subclasses)."""

    def __init__(
        self,
        url: str,
        max_bytes: int | None,
        deadline_s: float | None,
        *,
        too_large: type[ResponseTooLarge] = ResponseTooLarge,
        too_slow: type[ResponseTooSlow] = ResponseTooSlow,
    ) -> None:
        self.url = url
        self.max_bytes = max_bytes
        self.deadline_s = deadline_s
        self.give_up_at = time.monotonic() + deadline_s if deadline_s is not None else None
        self.received = 0
        self._too_large = too_large
        self._too_slow = too_slow

    def declared(self, content_length: str | None) -> None:
        if self.max_bytes is None or content_length is None:
            return
        length = content_length.strip()
        if length.isdigit() and int(length) > self.max_bytes:
            raise self._too_large(self.url, self.max_bytes, int(length))

    def take(self, n: int) -> None:
        self.received += n
        if self.max_bytes is not None and self.received > self.max_bytes:
            raise self._too_large(self.url, self.max_bytes)
        if self.give_up_at is not None and time.monotonic() > self.give_up_at:
            assert self.deadline_s is not None
            raise self._too_slow(self.url, self.deadline_s, self.received)

    def read(self, chunks: Iterable[bytes]) -> bytes:
        """All of ``chunks`` within the budget."""
        out = bytearray()
        for chunk in chunks:
            self.take(len(chunk))
            out += chunk
        return bytes(out)


def refuse_encoding(url: str, content_encoding: str | None) -> str | None:
    """The reason to refuse an answer with this Content-Encoding (``None``: plain bytes)."""
    enc = (content_encoding or "").strip().lower()
    if enc in ("", "identity"):
        return None
    return f"it is {enc}-compressed although identity was asked for"


class _BoundedStream(httpx.SyncByteStream):
    def __init__(self, inner: Any, budget: Budget, truncate_at: int | None) -> None:
        self._inner = inner
        self._budget = budget
        self._truncate_at = truncate_at

    def __iter__(self) -> Iterator[bytes]:
        for chunk in self._inner:
            if self._truncate_at is not None:  # an error body: keep its start, then stop
                chunk = chunk[: self._truncate_at - self._budget.received]
            self._budget.take(len(chunk))
            if chunk:
                yield chunk
            if self._truncate_at is not None and self._budget.received >= self._truncate_at:
                return

    def close(self) -> None:
        close = getattr(self._inner, "close", None)
        if close is not None:
            close()


def _hook(max_bytes: int | None, deadline_s: float) -> Any:
    def bound(response: httpx.Response) -> None:
        url = str(response.request.url)
        reason = refuse_encoding(url, response.headers.get("content-encoding"))
        if reason is not None:
            raise BodyRefused(url, reason)
        if not response.is_success:  # its start is enough; within the deadline too
            budget = Budget(url, None, deadline_s, too_slow=BodyTooSlow)
            response.stream = _BoundedStream(response.stream, budget, ERROR_BODY_BYTES)
            return
        cap = response.request.extensions.get(MAX_BYTES, max_bytes)
        deadline = response.request.extensions.get(DEADLINE_S, deadline_s)
        budget = Budget(url, cap, deadline, too_large=BodyTooLarge, too_slow=BodyTooSlow)
        budget.declared(response.headers.get("content-length"))
        response.stream = _BoundedStream(response.stream, budget, None)

    return bound


def bounded_client(
    *,
    timeout: float | httpx.Timeout,
    max_bytes: int | None = DEFAULT_MAX_BYTES,
    deadline_s: float | None = None,
    **kwargs: Any,
) -> httpx.Client:
    """An ``httpx.Client`` (``kwargs`` as httpx takes them) whose answers are bounded: at most
    ``max_bytes`` per 2xx body (a request's ``MAX_BYTES`` extension overrides it), at most
    :data:`ERROR_BODY_BYTES` read of an error body, every body within ``deadline_s`` (default
    :data:`DEADLINE_FACTOR` x ``timeout``) of its headers; redirects are not followed."""
    if deadline_s is None:
        read = timeout.read if isinstance(timeout, httpx.Timeout) else timeout
        deadline_s = DEADLINE_FACTOR * (read if read is not None else 30.0)
    deadline = deadline_s
    headers = {"Accept-Encoding": "identity", **dict(kwargs.pop("headers", None) or {})}
    hooks = dict(kwargs.pop("event_hooks", None) or {})
    hooks["response"] = [*hooks.get("response", []), _hook(max_bytes, deadline)]
    return httpx.Client(
        timeout=timeout, headers=headers, event_hooks=hooks, follow_redirects=False, **kwargs
    )


def bounded_get(url: str, *, timeout: float, max_bytes: int = DEFAULT_MAX_BYTES) -> httpx.Response:
    """``GET url``, its body read within the bounds of :func:`bounded_client`."""
    with bounded_client(timeout=timeout, max_bytes=max_bytes) as client:
        return client.get(url)
