"""Task specs stored for callers who sign ``addTask`` themselves, until their task is on chain.

``POST /tasks`` stores the spec before the ``addTask`` that names it: the spec's CID is the
task's description. When the gateway holds no key for the caller it answers 409
``sign_locally`` and the caller may never relay the transaction, so each such request left a
spec in the store at no cost (the 2026-12-03 audit: ~5 KB a request, ~0.9 GB a day from one
client varying the seed). A caller may have at most ``per_address`` specs stored whose task
the index has not seen within ``window_s``; past that, 429 ``too_many_pending_specs`` until
one is added on chain or ages out. Specs already stored are not removed: the bound is on
what one address can add, not a garbage collector.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable

from backend.errors import RateLimited

PER_ADDRESS = 8
WINDOW_S = 3600.0
MAX_ADDRESSES = 10_000
"""Addresses remembered at once (the oldest entries are dropped past it)."""


class PendingSpecs:
    """Per address, the (time, CID) of the specs stored for tasks not yet seen on chain."""

    def __init__(
        self,
        per_address: int = PER_ADDRESS,
        window_s: float = WINDOW_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.per_address, self.window_s, self._clock = per_address, window_s, clock
        self._lock = threading.Lock()
        self._specs: dict[str, deque[tuple[float, str]]] = {}

    def reserve(
        self, address: str, cid: str, on_chain: Callable[[Iterable[str]], set[str]]
    ) -> None:
        """Raise :class:`RateLimited` if ``address`` has ``per_address`` specs pending
        (``on_chain`` names which of the given CIDs are already task descriptions), else count
        ``cid`` for it (a spec it already has pending counts once). One locked step, before the
        spec is stored: requests of one address sent in parallel each count before the next is
        admitted (checked and counted apart, they all passed the bound before any counted)."""
        with self._lock:
            self._admit(address, on_chain)
            self._add(address, cid)

    def _admit(self, address: str, on_chain: Callable[[Iterable[str]], set[str]]) -> None:
        now = self._clock()
        pending = self._specs.get(address, deque())
        while pending and now - pending[0][0] > self.window_s:
            pending.popleft()
        if len(pending) >= self.per_address:
            indexed = on_chain([cid for _, cid in pending])
            pending = deque((t, cid) for t, cid in pending if cid not in indexed)
        self._specs[address] = pending
        if len(pending) >= self.per_address:
            wait = self.window_s - (now - pending[0][0])
            raise RateLimited(
                "too_many_pending_specs",
                f"{address} has {len(pending)} task specs stored whose addTask is not on "
                f"chain yet: relay those transactions (POST /api/tx), or retry in "
                f"{int(wait) + 1} s",
                retry_after=wait,
            )

    def _add(self, address: str, cid: str) -> None:
        pending = self._specs.setdefault(address, deque())
        if all(c != cid for _, c in pending):
            pending.append((self._clock(), cid))
        if len(self._specs) > MAX_ADDRESSES:
            del self._specs[min(self._specs, key=self._last_added)]

    def _last_added(self, address: str) -> float:
        pending = self._specs[address]
        return pending[-1][0] if pending else 0.0
