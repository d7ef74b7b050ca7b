"""How much EVM execution one client of ``/rpc`` may ask for: a token bucket of gas.

``eth_call`` and ``eth_estimateGas`` are free and anonymous, but each runs on py-evm under the
gateway's chain lock (at roughly 3M gas a second): unbounded, one request for a 30M-gas loop
holds every write and read of the platform for ~10 s. geth answers the same threat with a gas
cap per call (``RPCGasCap``) and a time limit; here each execution is capped
(:data:`backend.settings.Settings.rpc_gas_cap`) and the gas each client's executions used is
drawn from its bucket, refilled at ``rpc_gas_per_minute``. A client whose bucket holds less
than one capped execution waits (JSON-RPC -32005, "limit exceeded", with the seconds to wait).
Calls that read the contracts' views use a few hundred thousand gas and never notice.

Each client's bucket bounds that client; a gateway-wide bucket (``rpc_gas_per_minute_total``)
bounds all remote clients together, drawn with the client's (:class:`JointBudget`): without it
many clients (or one host with many networks) kept the lock busy between them and starved the
platform's own writes.

The bucket counts any unit: ``POST /auth/nonce`` draws one per sign-in message it stores.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Literal

from backend.errors import RateLimited

MAX_CLIENTS = 10_000
"""Buckets kept at most; full ones are forgotten first (a full bucket is the default)."""
GATEWAY = "gateway"
"""The one key of the gateway-wide bucket."""


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


@dataclass(frozen=True)
class Refusal:
    """A draw that a bucket cannot pay: whose bucket (``client``: the caller's own;
    ``gateway``: all remote clients' together), its rate, and the whole seconds to wait."""

    bucket: Literal["client", "gateway"]
    per_minute: int
    wait_s: int


class JointBudget:
    """A client's bucket and the gateway-wide bucket, checked and drawn together (either may
    be None: not bounded). Both buckets' locks are held for one check-and-draw, always the
    client's first, so concurrent callers cannot all pass the checks before any draws."""

    def __init__(self, per_client: GasBudget | None, total: GasBudget | None) -> None:
        if per_client is not None and per_client is total:
            raise ValueError("the client buckets and the gateway-wide bucket must be two budgets")
        self.per_client, self.total = per_client, total

    def shortfall(self, client: str, gas: int) -> Refusal | None:
        """The first bucket (the client's, then the gateway's) not holding ``gas`` now."""
        with self._locked():
            return self._shortfall(client, gas)

    def take(self, client: str, gas: int) -> Refusal | None:
        """Draw ``gas`` from both buckets if both hold it now (None); else draw nothing."""
        with self._locked():
            refused = self._shortfall(client, gas)
            if refused is None:
                self._draw(client, gas)
            return refused

    def charge(self, client: str, gas: int) -> None:
        """Draw the gas an execution used from both buckets (they may go below zero)."""
        with self._locked():
            self._draw(client, gas)

    def _buckets(self, client: str) -> list[tuple[Literal["client", "gateway"], GasBudget, str]]:
        """(which, bucket, key) of the buckets that bound this draw, the client's first."""
        both: list[tuple[Literal["client", "gateway"], GasBudget | None, str]] = [
            ("client", self.per_client, client),
            ("gateway", self.total, GATEWAY),
        ]
        return [(which, budget, key) for which, budget, key in both if budget is not None]

    @contextlib.contextmanager
    def _locked(self) -> Iterator[None]:
        with contextlib.ExitStack() as held:
            for _, budget, _ in self._buckets(""):
                held.enter_context(budget._lock)
            yield

    def _shortfall(self, client: str, gas: int) -> Refusal | None:
        for which, budget, key in self._buckets(client):
            wait = budget._wait_s(key, gas, budget._clock())
            if wait:
                return Refusal(which, budget.per_minute, wait)
        return None

    def _draw(self, client: str, gas: int) -> None:
        for _, budget, key in self._buckets(client):
            budget._draw(key, gas, budget._clock())


@dataclass(frozen=True)
class GasMeter:
    """One remote client's draw on the ``/rpc`` gas budgets, for the executions its ``/api``
    writes run under the chain lock: the gas estimate of a transaction the gateway hands back
    to sign (``sign_locally``) and a transaction relayed through ``POST /api/tx``. Without it a
    client asking again and again for an unsigned ``allocateTask`` held the lock for seconds a
    request at no cost, stalling every other chain access (docs/platform.md, "Gas budgets")."""

    budget: JointBudget
    client: str
    gas_cap: int

    def take(self, gas: int) -> None:
        """Draw ``gas`` before an execution, or raise :class:`RateLimited` (nothing drawn)."""
        refused = self.budget.take(self.client, gas)
        if refused is not None:
            raise used_up(refused)

    def check(self, gas: int) -> None:
        """Raise :class:`RateLimited` unless both buckets hold ``gas`` now (nothing drawn)."""
        refused = self.budget.shortfall(self.client, gas)
        if refused is not None:
            raise used_up(refused)

    def charge(self, gas: int) -> None:
        """Draw the gas an execution used, after it ran."""
        self.budget.charge(self.client, gas)


def used_up(refused: Refusal) -> RateLimited:
    whose = "all remote clients' together" if refused.bucket == "gateway" else "this client's"
    return RateLimited(
        "gas_budget_used",
        f"{whose} chain execution budget ({refused.per_minute} gas a minute, shared with /rpc) "
        f"is used up: retry in {refused.wait_s} s",
        retry_after=refused.wait_s,
    )
