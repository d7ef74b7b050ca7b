"""The embedded demo chain's faucet: gas money for a fresh key, rate-limited.

eth-tester charges the base fee, and refuses even ``eth_call`` from an account that could not
pay it, so a newcomer's own key needs some native currency before it can register. The faucet
sends ``amount`` from the deployer account to a caller holding less than ``threshold``. It
exists only on the embedded chain in development mode (the gateway creates it only there), and
it is rate-limited: one top-up per address per ``interval_s``, ``per_client_per_minute``
top-ups per client (its IPv4 address or IPv6 network, the route's ``client_key``, whatever keys
it signs in with: fresh keys cost nothing, so one client could otherwise take the whole overall
budget and starve newcomers; a host picks any address of its /64), ``per_minute``
top-ups over all addresses, and at most ``max_per_address`` top-ups per address ever (while the
gateway runs: an address that sends its gas money away does not qualify again and again), so
nobody drains the deployer or fills blocks with it. Requests that need no top-up (balance
already at the threshold) are not counted.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from backend.errors import RateLimited
from backend.services.chain import ChainService
from backend.settings import Settings

FAUCET_WEI = 10 * 10**18
FAUCET_THRESHOLD_WEI = 10**18
WINDOW_S = 60.0
PER_CLIENT_PER_MINUTE = Settings.model_fields["faucet_per_client_per_minute"].default
MAX_PER_ADDRESS = Settings.model_fields["faucet_max_per_address"].default



class FaucetLimited(RateLimited):
    """Too many top-ups: ``rule`` names the limit, ``retry_after`` is in whole seconds (None:
    waiting does not help, the address had all its top-ups)."""

    def __init__(self, rule: str, msg: str, retry_after: int | None) -> None:
        super().__init__(rule, msg, retry_after=retry_after)


@dataclass(frozen=True)
class TopUp:
    address: str
    balance_wei: int
    tx_hash: str | None


class Faucet:
    """Tops callers up from the deployer account, within the rate limits."""

    def __init__(
        self,
        service: ChainService,
        *,
        interval_s: float,
        per_minute: int,
        per_client_per_minute: int = PER_CLIENT_PER_MINUTE,
        max_per_address: int = MAX_PER_ADDRESS,
        amount_wei: int = FAUCET_WEI,
        threshold_wei: int = FAUCET_THRESHOLD_WEI,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.service = service
        self.interval_s = interval_s
        self.per_minute = per_minute
        self.per_client_per_minute = per_client_per_minute
        self.max_per_address = max_per_address
        self.amount_wei = amount_wei
        self.threshold_wei = threshold_wei
        self.clock = clock
        self._last: dict[str, float] = {}  # address -> time of its last top-up
        self._recent: deque[float] = deque()  # times of all top-ups in the last minute
        self._by_client: dict[str, deque[float]] = {}  # client -> its top-ups' times, last minute
        self._count: dict[str, int] = {}  # address -> top-ups it ever got
        self._lock = threading.Lock()

    def top_up(self, address: str, client: str | None = None) -> TopUp:
        """Send ``amount_wei`` to ``address`` if it holds less than the threshold; ``client``
        (the caller's key from the route: IPv4 address or IPv6 network) has its own rate; None
        counts for no client.

        Raises :class:`FaucetLimited` when a rate limit stops the top-up.
        """
        w3 = self.service.chain.w3
        with self._lock, self.service.lock:
            if w3.eth.get_balance(address) >= self.threshold_wei:  # type: ignore[arg-type]
                return TopUp(address, w3.eth.get_balance(address), None)  # type: ignore[arg-type]
            self._admit(address, client)
            tx_hash = self._send(address)
            return TopUp(address, w3.eth.get_balance(address), tx_hash)  # type: ignore[arg-type]

    def _admit(self, address: str, client: str | None) -> None:
        now = self.clock()
        while self._recent and now - self._recent[0] >= WINDOW_S:
            self._recent.popleft()
        for old in [a for a, t in self._last.items() if now - t >= self.interval_s]:
            del self._last[old]
        for key in list(self._by_client):
            times = self._by_client[key]
            while times and now - times[0] >= WINDOW_S:
                times.popleft()
            if not times:
                del self._by_client[key]
        if self._count.get(address, 0) >= self.max_per_address:
            raise FaucetLimited(
                "faucet_address_lifetime",
                f"an address gets at most {self.max_per_address} top-ups from the faucet; "
                f"{address} had them all (fund it from another account)",
                None,  # waiting does not help: no Retry-After
            )
        last = self._last.get(address)
        if last is not None:
            wait = self.interval_s - (now - last)
            raise FaucetLimited(
                "faucet_address_rate",
                f"one top-up per address every {self.interval_s:g} s",
                max(1, math.ceil(wait)),
            )
        mine = self._by_client.get(client) if client is not None else None
        if mine is not None and len(mine) >= self.per_client_per_minute:
            wait = WINDOW_S - (now - mine[0])
            raise FaucetLimited(
                "faucet_client_rate",
                f"the faucet sends at most {self.per_client_per_minute} top-ups per minute to "
                "one client, whatever addresses it signs in with",
                max(1, math.ceil(wait)),
            )
        if len(self._recent) >= self.per_minute:
            wait = WINDOW_S - (now - self._recent[0])
            raise FaucetLimited(
                "faucet_global_rate",
                f"the faucet sends at most {self.per_minute} top-ups per minute",
                max(1, math.ceil(wait)),
            )
        self._last[address] = now
        self._recent.append(now)
        self._count[address] = self._count.get(address, 0) + 1
        if client is not None:
            self._by_client.setdefault(client, deque()).append(now)

    def _send(self, address: str) -> str:
        chain = self.service.chain
        w3 = chain.w3
        admin = chain._keys[self.service.platform.admin]  # type: ignore[index]
        base = w3.eth.get_block("latest").get("baseFeePerGas", 0) or 0
        tx = {
            "to": address,
            "value": self.amount_wei,
            "gas": 21_000,
            "chainId": chain.chain_id,
            "nonce": w3.eth.get_transaction_count(admin.address, "pending"),
            "maxFeePerGas": 2 * base,
            "maxPriorityFeePerGas": 0,
        }
        signed = admin.sign_transaction(tx)  # type: ignore[arg-type]
        sent = w3.eth.send_raw_transaction(signed.raw_transaction)
        w3.eth.wait_for_transaction_receipt(sent)
        return "0x" + bytes(sent).hex()
