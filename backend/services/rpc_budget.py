"""How much EVM execution one client of ``/rpc`` may ask for: a token bucket of gas.

``eth_call`` and ``eth_estimateGas`` are free and anonymous, but each runs on py-evm under the
gateway's chain lock (at roughly 3M gas a second): unbounded, one request for a 30M-gas loop
holds every write and read of the platform for ~10 s. geth answers the same threat with a gas
cap per call (``RPCGasCap``) and a time limit; here each execution is capped
(:data:`backend.settings.Settings.rpc_gas_cap`) and the gas each client's executions used is
drawn from its bucket, refilled at ``rpc_gas_per_minute``. A client whose bucket holds less
than one capped execution waits (JSON-RPC -32005, "limit exceeded", with the seconds to wait).
Calls that read the contracts' views use a few hundred thousand gas and never notice.

The bucket counts any unit: ``POST /auth/nonce`` draws one per sign-in message it stores.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

MAX_CLIENTS = 10_000
"""Buckets kept at most; full ones are forgotten first (a full bucket is the default)."""


class GasBudget:
    """Per-client gas buckets of capacity ``per_minute``, refilled continuously."""

    def __init__(self, per_minute: int, clock: Callable[[], float] = time.monotonic) -> None:
        if per_minute <= 0:
            raise ValueError(f"per_minute must be > 0, got {per_minute}")
        self.per_minute = per_minute
        self._clock = clock
        self._buckets: dict[str, tuple[float, float]] = {}  # client -> (tokens, at)
        self._lock = threading.Lock()

    def available(self, client: str) -> float:
        """Gas the client may still use now."""
        with self._lock:
            return self._refilled(client, self._clock())

    def wait_s(self, client: str, gas: int) -> int:
        """Whole seconds until the client's bucket holds ``gas`` (0: now)."""
        with self._lock:
            return self._wait_s(client, gas, self._clock())

    def take(self, client: str, amount: int) -> int:
        """Draw ``amount`` now if the bucket holds it and return 0; else draw nothing and
        return the whole seconds to wait. One step under the lock: callers racing for the
        last tokens cannot all pass the check before any of them draws."""
        with self._lock:
            now = self._clock()
            wait = self._wait_s(client, amount, now)
            if not wait:
                self._draw(client, amount, now)
            return wait

    def charge(self, client: str, gas: int) -> None:
        """Draw the gas an execution used (the bucket may go below zero: the client waits)."""
        with self._lock:
            self._draw(client, gas, self._clock())

    def _wait_s(self, client: str, gas: int, now: float) -> int:
        missing = gas - self._refilled(client, now)
        return 0 if missing <= 0 else math.ceil(60.0 * missing / self.per_minute)

    def _draw(self, client: str, gas: int, now: float) -> None:
        tokens = self._refilled(client, now) - gas
        if client not in self._buckets and len(self._buckets) >= MAX_CLIENTS:
            self._forget_full(now)
        self._buckets[client] = (tokens, now)

    def _refilled(self, client: str, now: float) -> float:
        tokens, at = self._buckets.get(client, (float(self.per_minute), now))
        return min(float(self.per_minute), tokens + (now - at) * self.per_minute / 60.0)

    def _forget_full(self, now: float) -> None:
        for client in [c for c in self._buckets if self._refilled(c, now) >= self.per_minute]:
            del self._buckets[client]
        if len(self._buckets) >= MAX_CLIENTS:  # all busy: drop the oldest entries
            for client in sorted(self._buckets, key=lambda c: self._buckets[c][1])[
                : len(self._buckets) // 2
            ]:
                del self._buckets[client]
