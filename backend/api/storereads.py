"""How many requests use the content store at once, overall and per client address.

A read of content nobody holds waits for the node's find timeout (10 s on kubo) in one of the
threads every sync route shares (anyio's pool of 40). Unbounded, 40 anonymous requests for
absent CIDs (``GET /api/blocks/{cid}``) every 10 s would stall the whole REST API. Past
``max_store_reads_per_client`` a client gets 429 ``store_reads_per_client``, past
``max_store_reads`` everyone gets 503 ``store_reads_busy``, both at once and with Retry-After,
so the threads left serve the routes that do not touch the store (docs/platform.md,
"Overload").
"""

from __future__ import annotations

import threading

from backend.api.errors import RuleError


class StoreReads:
    """Requests holding a store slot: taken by the ``StoreDep`` dependency, released when the
    route returns. Thread-safe (a lock around two counters)."""

    def __init__(self, limit: int, per_client: int, retry_after: int) -> None:
        if limit < 1 or per_client < 1:
            raise ValueError(f"limits must be >= 1, got {limit} and {per_client}")
        self.limit, self.per_client, self.retry_after = limit, per_client, retry_after
        self.total = 0
        self.by_client: dict[str, int] = {}
        self.refused = 0  # for tests and metrics
        self._lock = threading.Lock()

    def enter(self, client: str) -> None:
        """Take a slot for ``client``; RuleError 429 / 503 (never waits) when none is free."""
        with self._lock:
            if self.by_client.get(client, 0) >= self.per_client:
                self.refused += 1
                raise RuleError(
                    429,
                    "store_reads_per_client",
                    f"at most {self.per_client} requests reading the content store at once per "
                    "client (max_store_reads_per_client); wait for one to finish",
                    headers={"Retry-After": str(self.retry_after)},
                )
            if self.total >= self.limit:
                self.refused += 1
                raise RuleError(
                    503,
                    "store_reads_busy",
                    f"the gateway is at its limit of {self.limit} requests reading the content "
                    f"store at once (max_store_reads); retry after {self.retry_after} s",
                    headers={"Retry-After": str(self.retry_after)},
                )
            self.total += 1
            self.by_client[client] = self.by_client.get(client, 0) + 1

    def leave(self, client: str) -> None:
        with self._lock:
            self.total -= 1
            left = self.by_client[client] - 1
            if left:
                self.by_client[client] = left
            else:
                del self.by_client[client]
