"""Slots held at once, overall and per client: what bounds streamed downloads
(``routes.models``) and requests reading the content store (``deps.get_store``). A client is
its :func:`backend.api.client_key.client_key` (an IPv6 client is its /64, not each address).

A read of content nobody holds waits for the node's find timeout (10 s on kubo) in one of the
threads every sync route shares (anyio's pool of 40); a download waits on its client. Either,
unbounded, lets a few clients hold what everyone else needs (docs/platform.md, "Overload").
"""

from __future__ import annotations

import threading
from typing import Literal


class ClientSlots:
    """``limit`` slots overall, ``per_client`` of them for one client key. Thread-safe
    (sync routes take and give back slots from the thread pool, downloads on the event loop)."""

    def __init__(self, limit: int, per_client: int) -> None:
        if limit < 1 or per_client < 1:
            raise ValueError(f"limits must be >= 1, got {limit} and {per_client}")
        self.limit, self.per_client = limit, per_client
        self.total = 0
        self.by_client: dict[str, int] = {}
        self._lock = threading.Lock()

    def take(self, client: str) -> Literal["client", "total"] | None:
        """Take a slot for ``client`` (None), or say which bound is full; never waits."""
        with self._lock:
            if self.by_client.get(client, 0) >= self.per_client:
                return "client"
            if self.total >= self.limit:
                return "total"
            self.total += 1
            self.by_client[client] = self.by_client.get(client, 0) + 1
            return None

    def release(self, client: str) -> None:
        with self._lock:
            self.total -= 1
            left = self.by_client[client] - 1
            if left:
                self.by_client[client] = left
            else:
                del self.by_client[client]
