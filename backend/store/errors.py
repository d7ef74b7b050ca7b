"""Typed errors of the content store, shared by both backends.

Callers (gateway, worker daemon, CLI) catch these by type: a :class:`CIDMismatch` means the bytes
must not be used, :class:`StoreUnavailable` means "try again later", :class:`NotFound` means the
content is not (or no longer) there, and its subclass :class:`FindTimeout` that a node gave up
looking for it in time (worth retrying).
"""

from __future__ import annotations


class StoreError(Exception):
    """Base class of every content-store error."""


class InvalidCID(StoreError, ValueError):
    """A CID string or binary that cannot be parsed, or uses a codec/hash this store does not
    support (only raw and dag-pb blocks hashed with sha2-256)."""


class InvalidContent(StoreError):
    """Blocks whose hashes are right but whose structure is not a UnixFS file we can read
    (e.g. a directory, or a node whose declared sizes do not add up)."""


class CIDMismatch(StoreError):
    """Bytes received (from disk or from a node) do not hash to the CID they were asked for, or a
    node reports a different CID than the one computed locally for an upload."""

    def __init__(self, expected: str, actual: str, where: str = "") -> None:
        self.expected = expected
        self.actual = actual
        self.where = where
        suffix = f" ({where})" if where else ""
        super().__init__(
            f"content does not match its CID: expected {expected}, got {actual}{suffix}"
        )


class ContentTooLarge(StoreError):
    """Content (or a single block) exceeds the configured size bound; raised as early as the size
    is known, before the rest is read."""

    def __init__(self, size: int | None, limit: int, what: str = "content") -> None:
        self.size = size
        self.limit = limit
        shown = f"{size} bytes" if size is not None else "more bytes"
        super().__init__(f"{what} is too large: {shown} > limit of {limit} bytes")


class NotFound(StoreError, KeyError):
    """The CID (or one of its blocks) is not in the store / not retrievable from the node."""

    def __init__(self, cid: str, detail: str = "") -> None:
        self.cid = cid
        msg = f"content not found: {cid}" + (f" ({detail})" if detail else "")
        super().__init__(msg)

    def __str__(self) -> str:  # KeyError would otherwise repr() the message
        return str(self.args[0])


class FindTimeout(NotFound):
    """The node gave up looking for the CID within its find timeout (Kubo: "context deadline
    exceeded", js-ipfs: "request timed out"): the content may come back with its provider, so
    a caller that can wait retries it like :class:`StoreUnavailable`. A :class:`NotFound`, so
    callers that treat both alike (the gateway's 404s, ``has``) keep working."""

    def __init__(self, cid: str, detail: str = "", after: float | None = None) -> None:
        self.cid = cid
        within = f" within {after:g} s" if after is not None else ""
        msg = f"timed out finding {cid}{within}" + (f" ({detail})" if detail else "")
        Exception.__init__(self, msg + "; its provider may be offline, try again later")


class StoreUnavailable(StoreError):
    """The store cannot be reached (node down, connection refused, timeout, node-side 5xx).

    Transient: retry the same call after ``retry_after`` seconds (with backoff); the operation
    is idempotent (adding the same bytes yields the same CID).
    """

    def __init__(self, url: str, reason: str, retry_after: float = 5.0) -> None:
        self.url = url
        self.reason = reason
        self.retry_after = retry_after
        super().__init__(
            f"content store unavailable at {url}: {reason}; retry in {retry_after:g} s "
            "(the call is idempotent)"
        )
