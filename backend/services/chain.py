"""The gateway's chain connection: one :class:`ChainService` per app (on ``app.state.chain``).

* embedded (``DRLAAS_CHAIN=embedded``): an in-process eth-tester chain; the platform (UMC, TMC,
  MMC) is deployed at start and its funded accounts become the demo users (``DemoKeys``, names
  ``admin``, ``user1`` ...), in development mode only.
* rpc (``DRLAAS_CHAIN=http://node:8545``): the contracts' addresses come from the JSON file
  named by ``DRLAAS_CONTRACTS`` (``{"UsersManager": "0x..", "TasksManager": "0x..",
  "ModelsManager": "0x..", "deploy_block": N}``); the gateway holds no keys unless given demo
  keys explicitly.

Writes act for the authenticated address only (docs/platform.md, "Signing"): when the
gateway holds that address's demo key it signs and sends; otherwise :meth:`ChainService.send`
raises :class:`SignLocally` carrying the unsigned transaction (answered as 409), which the
client signs and relays through ``POST /api/tx`` (:meth:`ChainService.relay_raw`).

eth-tester is not thread-safe and nonces must not race, so every chain access from request
handlers, the ``/rpc`` endpoint and the indexer goes through :attr:`ChainService.lock`, a
:class:`FairRLock`: granted in arrival order, so a platform write waits for the holders ahead
of it, not for every anonymous ``/rpc`` read that keeps arriving after it.
"""

from __future__ import annotations

import ast
import dataclasses
import json
import os
import re
import threading
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import rlp  # type: ignore[import-untyped]
from eth_account import Account
from eth_account.signers.local import LocalAccount
from eth_account.typed_transactions import TypedTransaction
from eth_tester.exceptions import TransactionFailed
from hexbytes import HexBytes
from web3 import Web3
from web3.exceptions import TimeExhausted

from backend.auth import DemoKeys
from backend.chain.client import GAS_MARGIN, Chain, ContractHandle, Receipt, typed_revert
from backend.chain.errors import ContractError, UnknownRevert
from backend.chain.platform import CONTRACT_NAMES, Platform, connect_platform, deploy_platform
from backend.chain.rawtx import RawTx, RawTxError, check_chain, decode_raw_tx
from backend.errors import (
    Conflict,
    DomainError,
    Forbidden,
    Invalid,
    NotFound,
    PaymentRequired,
    TooLarge,
    Unavailable,
)
from backend.services.rpc_budget import GasMeter
from backend.services.rpc_call import OutOfGas, bounded_estimate, unpriced_call
from backend.settings import Settings

CONTRACTS_ENV = "DRLAAS_CONTRACTS"
EMBEDDED_ACCOUNTS = 20
"""Funded accounts of the embedded chain: ``admin`` + 19 demo users."""
ALL_GPU_SERIES = (1 << 256) - 1
"""Accepted GPU series of the embedded TMC: every code including 0 (no GPU), since the MDRL core
trains on CPUs (the deployment default accepts only workers with a GPU)."""

# Contract errors a client can cause, by the kind of failure they are (the rest: Conflict).
_ERROR_KIND: dict[str, type[DomainError]] = {
    "NotRequester": Forbidden,
    "NotTaskRequester": Forbidden,
    "NotAllocationRequester": Forbidden,
    "NotWorker": Forbidden,
    "NotAdmin": Forbidden,
    "NotParticipant": Forbidden,
    "NotOutcomeOwner": Forbidden,
    "NotSelfOrAdmin": Forbidden,
    "NotApproved": Forbidden,
    "TooManyDomains": Invalid,
    "OwnerNotInDomain": Invalid,
    "UnknownTask": NotFound,
    "BadPayment": Invalid,
    "RewardBelowMinimum": Invalid,
    "PriceBelowMinimum": Invalid,
    "BadDuration": Invalid,
}

# Node-side refusals (before any contract code runs), by a lower-case fragment of the message
# of eth-tester (py-evm) or a JSON-RPC node (geth, anvil, besu): (kind, rule, what to do).
# Insufficient funds is PaymentRequired (402): the account must be funded first (the embedded
# demo's faucet, POST /api/chain/faucet, or the consortium's operator); the request itself is
# well-formed. A stale nonce is a Conflict (409) with the chain's state; a transaction built
# wrong (gas below the intrinsic cost or above the block limit, fee below the base fee) is
# Invalid (422).
_NODE_RULES: tuple[tuple[tuple[str, ...], type[DomainError], str, str], ...] = (
    (
        ("insufficient funds", "not have enough balance", "cannot afford"),
        PaymentRequired,
        "insufficient_funds",
        "the sender's balance does not cover the transaction's value plus gas; fund it first",
    ),
    (
        ("nonce too low", "invalid transaction nonce", "nonce too high", "nonce has already"),
        Conflict,
        "nonce_mismatch",
        "the transaction's nonce is not the sender's next one; re-read it and sign again",
    ),
    (
        ("intrinsic gas too low", "gas cannot be negative"),
        Invalid,
        "intrinsic_gas_too_low",
        "the gas limit is below what the transaction needs before running any code",
    ),
    (
        ("exceeds block gas limit", "exceeds gas limit", "gas limit reached"),
        Invalid,
        "gas_limit_exceeded",
        "the gas limit is above the block's gas limit",
    ),
    (
        ("lower than block's base fee", "less than block base fee", "fee cap less than"),
        Invalid,
        "fee_too_low",
        "the max fee per gas is below the block's base fee",
    ),
    (
        ("non-payable", "nonpayable", "value mismatch"),
        Invalid,
        "value_not_accepted",
        "the called function does not take this value",
    ),
)


RELAY_RECEIPT_TIMEOUT_S = 120.0
"""Longest wait of ``POST /api/tx`` for the receipt of a transaction the node accepted."""


class TxPending(Unavailable):
    """A relayed transaction the node accepted but did not mine within
    :data:`RELAY_RECEIPT_TIMEOUT_S`: it may still be mined (the route answers 504
    ``tx_pending`` with its hash, to be looked up instead of sent again)."""

    def __init__(self, tx_hash: str, waited_s: float) -> None:
        super().__init__(
            "tx_pending",
            f"transaction {tx_hash} was accepted by the node but not mined within {waited_s:g} s;"
            " look its receipt up (eth_getTransactionReceipt) rather than sending it again",
        )
        self.tx_hash = tx_hash


def _nonce_and_max_fee(raw: bytes) -> tuple[int, int]:
    """Nonce and max fee per gas (gasPrice for legacy and EIP-2930 transactions) of a raw
    transaction that :func:`decode_raw_tx` read."""
    try:
        if raw[0] < 0x7F:
            fields = TypedTransaction.from_bytes(HexBytes(raw)).as_dict()
            fee = fields["maxFeePerGas"] if "maxFeePerGas" in fields else fields["gasPrice"]
            return int(fields["nonce"]), int(fee)
        items = rlp.decode(raw)
        return int.from_bytes(items[0], "big"), int.from_bytes(items[1], "big")
    except Exception:  # rlp / eth_account raise several types on malformed input
        raise Invalid("tx_invalid", "cannot read the transaction's nonce and fee") from None


class SignLocally(Exception):
    """The gateway holds no key for ``sender``: the client must sign ``tx`` and POST it to
    ``/api/tx``. Answered as 409 ``{"detail": {"rule": "sign_locally", "msg", "tx"}}``."""

    def __init__(self, sender: str, tx: dict[str, Any], description: str, then: str = "") -> None:
        super().__init__(f"sign_locally: {description} for {sender}")
        self.sender = sender
        self.tx = tx
        self.description = description
        self.then = then
        """``"repeat"``: once ``tx`` is mined, send the same request again (it was a first
        step, e.g. the commitment before ``POST /models``); empty: ``tx`` is the request."""


def _snake(name: str) -> str:
    return re.sub(r"(?<!^)(?=[A-Z])", "_", name).lower()


def contract_rule_error(exc: ContractError) -> DomainError:
    """A typed contract revert as a domain error: rule = snake_case error name (e.g.
    ``tasks_not_offered_worker``), message with the decoded arguments."""
    suffix = next((k for k in _ERROR_KIND if exc.name.endswith(k)), None)
    kind = _ERROR_KIND[suffix] if suffix else Conflict
    return kind(_snake(exc.name), f"the contract refused the transaction: {exc}")


def node_rule_error(exc: BaseException) -> DomainError | None:
    """A node's refusal of a transaction (balance, nonce, gas, fee) as a 4xx naming the
    rule, or None when ``exc`` is none of those. Looks through the exception's chain: web3
    wraps eth-tester's and the node's errors."""
    seen: BaseException | None = exc
    texts = []
    while seen is not None and len(texts) < 8:
        texts.append(str(seen).lower())
        seen = seen.__cause__ or seen.__context__
    text = " | ".join(texts)
    for fragments, kind, rule, what in _NODE_RULES:
        if any(f in text for f in fragments):
            detail = _readable(str(exc))[:300]
            return kind(rule, f"the chain refused the transaction: {what} ({detail})")
    return None


def _readable(text: str) -> str:
    """A node's message with Python bytes reprs (eth-tester's ``Sender b'...'``) as hex."""

    def hexed(m: re.Match[str]) -> str:
        try:
            return "0x" + ast.literal_eval(m.group(0)).hex()
        except (ValueError, SyntaxError):
            return m.group(0)

    return re.sub(r"b'(?:[^'\\]|\\.)*'|b\"(?:[^\"\\]|\\.)*\"", hexed, text)


def _jsonable_tx(tx: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in tx.items():
        if isinstance(v, bytes):
            out[k] = "0x" + v.hex()
        elif isinstance(v, int) and not isinstance(v, bool):
            out[k] = v if v < 2**53 else hex(v)
        else:
            out[k] = v
    out.setdefault("type", 2)
    return out


class FairRLock:
    """A reentrant lock granted first come, first served.

    ``threading.RLock`` lets whoever asks at the moment it is released take it: a thread that
    releases and asks again at once (a ``/rpc`` batch between its items, a stream of reads
    from many clients) usually wins over a thread that has waited longer, so a platform write
    (task creation, ``POST /api/tx``) could wait for as long as reads kept coming. Here a
    release hands the lock to the longest waiter. Reentrant like ``RLock``; used with ``with``.
    """

    def __init__(self) -> None:
        self._mutex = threading.Lock()  # guards the fields below; held only briefly
        self._owner: int | None = None
        self._depth = 0
        self._waiters: deque[tuple[int, threading.Lock]] = deque()  # (thread, its gate)

    def acquire(self, blocking: bool = True, timeout: float = -1) -> bool:
        me = threading.get_ident()
        with self._mutex:
            if self._owner == me:
                self._depth += 1
                return True
            if self._owner is None and not self._waiters:
                self._owner, self._depth = me, 1
                return True
            if not blocking:
                return False
            gate = threading.Lock()
            gate.acquire()  # opened by the release that hands the lock to this thread
            self._waiters.append((me, gate))
        try:
            if gate.acquire(timeout=timeout if timeout >= 0 else -1):
                return True  # the releaser made this thread the owner before opening the gate
        except BaseException:  # interrupted (KeyboardInterrupt): never own it unknowingly
            with self._mutex:
                if self._owner == me:
                    self._hand_on()
                else:
                    self._waiters.remove((me, gate))
            raise
        with self._mutex:  # timed out, unless a release handed the lock over meanwhile
            if self._owner == me:
                return True
            self._waiters.remove((me, gate))
            return False

    def release(self) -> None:
        with self._mutex:
            if self._owner != threading.get_ident():
                raise RuntimeError("cannot release a FairRLock this thread does not hold")
            self._depth -= 1
            if not self._depth:
                self._hand_on()

    def _hand_on(self) -> None:
        """Give the lock to the longest waiter, or free it (the mutex is held)."""
        if self._waiters:
            self._owner, gate = self._waiters.popleft()
            self._depth = 1
            gate.release()
        else:
            self._owner, self._depth = None, 0

    def __enter__(self) -> bool:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


@dataclass
class ChainService:
    """Chain + deployed platform + (development) demo keys + the lock that serialises access."""

    chain: Chain
    platform: Platform
    deploy_block: int
    demo_keys: DemoKeys | None = None
    lock: FairRLock = field(default_factory=FairRLock)
    meter: GasMeter | None = None
    """The remote client this view acts for (:meth:`for_client`): the executions its writes
    run on the embedded chain are drawn from its gas budget. None: not metered."""

    def for_client(self, meter: GasMeter | None) -> ChainService:
        """This service (same chain, platform, keys and lock) acting for one metered client."""
        return dataclasses.replace(self, meter=meter)

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_settings(cls, settings: Settings) -> ChainService:
        if settings.chain_service.embedded:
            return cls.embedded(settings)
        return cls.rpc(settings)

    @classmethod
    def embedded(cls, settings: Settings, accounts: int = EMBEDDED_ACCOUNTS) -> ChainService:
        """The embedded chain in ``<data_dir>/chain`` (:mod:`backend.chain.durable`): reopened
        with its deployment when it exists, else a new chain with the platform deployed
        (windows from settings) and the deployment recorded in the same file."""
        chain = Chain.embedded(accounts=accounts, directory=settings.data_dir / "chain")
        backend = chain._tester.backend  # type: ignore[union-attr]
        recorded = backend.kv.get_meta("deployment")
        if recorded is not None:
            service = cls.attach(chain, recorded)
        else:
            platform = deploy_platform(
                chain,
                accept_window=settings.accept_window_s,
                review_window=settings.review_window_s,
                accepted_gpus=ALL_GPU_SERIES,
                min_reward_per_hour=settings.min_reward_per_hour_wei,
                min_model_price=settings.min_model_price_wei,
                # development chain: registration makes a worker a candidate at once
                worker_approval=False,
            )
            service = cls(chain, platform, platform.deployed_at)
            backend.kv.set_meta("deployment", service.addresses())
        if settings.demo_keys_allowed:
            service.demo_keys = DemoKeys(settings)
            for i, address in enumerate(chain.accounts):
                service.demo_keys.add("admin" if i == 0 else f"user{i}", chain._keys[address])  # type: ignore[index]
        return service

    @classmethod
    def rpc(
        cls, settings: Settings, contracts: str | os.PathLike[str] | None = None
    ) -> ChainService:
        """A real node; addresses from ``contracts`` or the file named by DRLAAS_CONTRACTS."""
        path = contracts or os.environ.get(CONTRACTS_ENV)
        if not path:
            raise RuntimeError(
                f"{CONTRACTS_ENV} must name a JSON file of contract addresses when DRLAAS_CHAIN "
                f"is a node URL ({settings.chain})"
            )
        addresses = load_contracts(path)
        keys_allowed = settings.demo_keys_allowed
        chain = Chain.rpc(settings.chain, private_keys=None if keys_allowed else [])
        return cls.attach(chain, addresses, demo=keys_allowed, settings=settings)

    @classmethod
    def attach(
        cls,
        chain: Chain,
        addresses: dict[str, Any],
        *,
        demo: bool = False,
        settings: Settings | None = None,
    ) -> ChainService:
        """Handles on an existing deployment (``addresses`` as :func:`load_contracts` gives)."""
        platform = connect_platform(
            chain,
            addresses,
            admin=addresses.get("admin") or (chain.accounts[0] if chain.accounts else ""),
        )
        keys = None
        if demo and settings is not None and chain.accounts:
            keys = DemoKeys(settings)
            for i, address in enumerate(chain.accounts):
                keys.add("admin" if i == 0 else f"user{i}", chain._keys[address])  # type: ignore[index]
        return cls(chain, platform, int(addresses.get("deploy_block", 0)), keys)

    def addresses(self) -> dict[str, Any]:
        """The deployment as DRLAAS_CONTRACTS JSON (other processes attach with it)."""
        return self.platform.record(self.deploy_block)

    # -- signing --------------------------------------------------------------------------------
    def signer(self, address: str) -> LocalAccount | None:
        """The demo key of ``address`` if the gateway holds it (development only)."""
        if self.demo_keys is None:
            return None
        for name in self.demo_keys.names:
            account = self.demo_keys.account(name)
            if account.address == address:
                return account
        return None

    def send(
        self,
        sender: str,
        handle: ContractHandle,
        fn: str,
        *args: Any,
        value: int = 0,
        description: str = "",
        then: str = "",
    ) -> Receipt:
        """``handle.fn(*args)`` sent by ``sender``: signed here with its demo key, or
        :class:`SignLocally` with the unsigned transaction. Reverts -> domain errors."""
        account = self.signer(sender)
        with self.lock:
            try:
                if account is None:
                    raise SignLocally(
                        sender,
                        self._unsigned(sender, handle, fn, args, value),
                        description or f"{handle.name}.{fn}",
                        then,
                    )
                self._ensure_key(account)
                return handle.transact(fn, *args, sender=sender, value=value)
            except ContractError as exc:
                raise contract_rule_error(exc) from None
            except (SignLocally, DomainError):
                raise
            except Exception as exc:  # node refusals: eth-tester/web3 raise several types
                mapped = node_rule_error(exc)
                if mapped is None:
                    raise
                raise mapped from None

    def _ensure_key(self, account: LocalAccount) -> None:
        # Chain signs only for keys it was built with; a demo key added later joins them.
        keys: dict[Any, LocalAccount] = self.chain._keys
        if account.address not in keys:
            keys[account.address] = account
            self.chain.accounts.append(account.address)

    def _unsigned(
        self, sender: str, handle: ContractHandle, fn: str, args: tuple[Any, ...], value: int
    ) -> dict[str, Any]:
        w3 = self.chain.w3
        f = handle.contract.functions[fn](*args)
        gas = self._estimate(sender, handle, fn, args, value)  # typed revert first
        base = w3.eth.get_block("latest").get("baseFeePerGas", 0) or 0
        tx = f.build_transaction(  # type: ignore[arg-type]
            {
                "from": sender,
                "value": value,
                "nonce": w3.eth.get_transaction_count(sender, "pending"),  # type: ignore[arg-type]
                "chainId": self.chain.chain_id,
                "gas": min(int(gas * GAS_MARGIN) + 10_000, 30_000_000),
                "maxPriorityFeePerGas": 0,
                "maxFeePerGas": 2 * base,
            }
        )
        need = int(tx["gas"]) * int(tx["maxFeePerGas"]) + value
        have = int(w3.eth.get_balance(sender))  # type: ignore[arg-type]
        if have < need:  # a transaction its sender could never pay for is not handed out
            raise PaymentRequired(
                "insufficient_funds",
                f"{sender} holds {have} wei; {handle.name}.{fn} may cost up to {need} wei (gas "
                f"limit x max fee + value): fund the account first",
            )
        return _jsonable_tx(dict(tx))

    def _estimate(
        self, sender: str, handle: ContractHandle, fn: str, args: tuple[Any, ...], value: int
    ) -> int:
        """The gas of ``handle.fn(*args)`` from ``sender``. For a metered client on the
        embedded chain: at most a few executions of at most its gas cap (``bounded_estimate``,
        not eth-tester's bisection from the block gas limit, ~25 runs), each drawn from its
        budget; refused up front when the budget does not hold one execution at the cap."""
        tester = self.chain._tester
        if self.meter is None or tester is None:
            return handle.estimate(fn, *args, sender=sender, value=value)
        meter = self.meter
        meter.check(meter.gas_cap)
        tx = {
            "from": sender,
            "to": handle.address,
            "data": handle.contract.encode_abi(fn, args=list(args)),
            "value": value,
        }
        try:
            return bounded_estimate(
                tester, tx, "pending", gas_cap=meter.gas_cap, charge=meter.charge
            )
        except TransactionFailed as exc:
            raise typed_revert(exc) from None
        except OutOfGas:
            raise TooLarge(
                "gas_cap",
                f"{handle.name}.{fn} needs more than this gateway's {meter.gas_cap} gas per "
                f"execution",
            ) from None

    def relay_raw(self, raw: bytes, expected_sender: str, gas_cap: int | None = None) -> Receipt:
        """Relay a transaction the client signed: its recovered sender must be the caller
        (403 ``tx_sender_mismatch``), its target one of the platform contracts, its gas limit
        at most ``gas_cap`` (422 ``tx_gas_cap``: the embedded chain executes under the
        platform's lock, so one relayed transaction must not hold it longer than an ``/rpc``
        call may)."""
        try:
            sender = Account.recover_transaction(raw)
        except Exception:  # eth_account raises several types for malformed transactions
            raise Invalid("tx_invalid", "not a signed Ethereum transaction") from None
        if sender != expected_sender:
            raise Forbidden(
                "tx_sender_mismatch",
                f"transaction is signed by {sender}; signed in as {expected_sender}",
            )
        try:
            tx = decode_raw_tx(raw)
            check_chain(tx, self.chain.chain_id)
        except RawTxError as exc:
            raise Invalid("tx_invalid", str(exc)) from None
        if gas_cap is not None and tx.gas > gas_cap:
            raise Invalid(
                "tx_gas_cap",
                f"the transaction's gas limit is {tx.gas}; this gateway relays at most "
                f"{gas_cap} gas per transaction (every platform call needs far less): sign it "
                f"again with a gas limit from eth_estimateGas",
            )
        to = tx.to
        targets = {h.address for h in self.platform.contracts}
        if to not in targets:
            raise Invalid(
                "tx_target", f"transaction goes to {to}; only platform contracts: {targets}"
            )
        if self.meter is not None and self.chain._tester is not None:
            self.meter.take(tx.gas)  # it runs under the lock: as eth_sendRawTransaction on /rpc
        nonce, max_fee = _nonce_and_max_fee(raw)
        w3 = self.chain.w3
        embedded = self.chain.kind == "embedded"
        with self.lock:
            # A node keeps a transaction with a nonce gap (or a fee below the base fee) queued
            # without mining it, so the relay would wait for a receipt that never comes:
            # refused here, with what to sign instead.
            expected = int(w3.eth.get_transaction_count(sender, "pending"))  # type: ignore[arg-type]
            if nonce != expected:
                raise Conflict(
                    "nonce_mismatch",
                    f"the transaction's nonce is {nonce}; the sender's next nonce is "
                    f"{expected}: sign it again with nonce {expected}",
                )
            base = w3.eth.get_block("latest").get("baseFeePerGas")
            if base is not None and max_fee < int(base):
                raise Invalid(
                    "fee_too_low",
                    f"the transaction's max fee per gas is {max_fee} wei; the chain's base fee "
                    f"is {int(base)} wei: sign it again with a max fee of at least that",
                )
            try:
                tx_hash = w3.eth.send_raw_transaction(raw)
            except Exception as exc:  # revert at inclusion (eth-tester) or node refusal
                raise node_rule_error(exc) or Conflict(
                    "tx_rejected", f"node refused the transaction: {exc}"
                ) from None
            if embedded:  # eth-tester is not thread-safe (and mines at once)
                raw_receipt = self._await_receipt(tx_hash)
        if not embedded:
            # A node is polled without the lock: the transaction is in its pool, so the
            # sender's next nonce already counts it, and other writes need not wait for a block.
            raw_receipt = self._await_receipt(tx_hash)
        events = self.chain._decode_logs(raw_receipt["logs"])
        receipt = Receipt(
            tx_hash="0x" + bytes(tx_hash).hex(),
            status=raw_receipt["status"],
            gas_used=raw_receipt["gasUsed"],
            effective_gas_price=raw_receipt.get("effectiveGasPrice", 0) or 0,
            block_number=raw_receipt["blockNumber"],
            events=events,
        )
        if receipt.status != 1:
            raise self._revert_reason(tx, sender, receipt)
        return receipt

    def _await_receipt(self, tx_hash: Any) -> Any:
        try:
            return self.chain.w3.eth.wait_for_transaction_receipt(
                tx_hash, timeout=RELAY_RECEIPT_TIMEOUT_S
            )
        except TimeExhausted:
            raise TxPending("0x" + bytes(tx_hash).hex(), RELAY_RECEIPT_TIMEOUT_S) from None

    def _revert_reason(self, tx: RawTx, sender: str, receipt: Receipt) -> DomainError:
        """Why a relayed transaction reverted, as the gateway's own routes say it (the
        contract's custom error as a rule): it is replayed as a call on its parent block's
        state, which the embedded chain (one transaction a block) makes exact."""
        call = {
            "from": sender,
            "to": tx.to,
            "data": "0x" + tx.data.hex(),
            "value": tx.value,
            "gas": tx.gas,
        }
        parent = receipt.block_number - 1
        try:
            with self.lock:
                tester = self.chain._tester
                if tester is not None:  # eth-tester's call hides the revert data in a message
                    unpriced_call(tester, call, parent, gas_cap=tx.gas)
                else:
                    self.chain.w3.eth.call(call, block_identifier=parent)  # type: ignore[arg-type]
        except Exception as exc:  # web3 / eth-tester raise several types for a revert
            typed = typed_revert(exc)
            if not isinstance(typed, UnknownRevert):
                return contract_rule_error(typed)
        return Conflict("tx_reverted", f"transaction {receipt.tx_hash} reverted")

    # -- views ----------------------------------------------------------------------------------
    def await_block_after(self, number: int) -> None:
        """Return once a block after ``number`` exists (a commitment mined there may be
        revealed now). The embedded chain mines one, under the lock as every write; a node
        is only polled, so the lock is not held for its block period."""
        if self.chain.kind == "embedded":
            with self.lock:
                self.chain.await_block_after(number)
        else:
            self.chain.await_block_after(number)

    def call(self, handle: ContractHandle, fn: str, *args: Any) -> Any:
        with self.lock:
            try:
                return handle.call(fn, *args)
            except ContractError as exc:
                raise contract_rule_error(exc) from None

    def block_number(self) -> int:
        with self.lock:
            return int(self.chain.w3.eth.block_number)


def load_contracts(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a DRLAAS_CONTRACTS file; errors name the variable, the file and the bad key."""
    p = Path(path)
    try:
        data = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise RuntimeError(f"{CONTRACTS_ENV}={p}: cannot read contract addresses: {exc}") from None
    if not isinstance(data, dict):
        raise RuntimeError(f"{CONTRACTS_ENV}={p}: expected a JSON object of addresses")
    for name in CONTRACT_NAMES:
        value = data.get(name)
        if not isinstance(value, str) or not Web3.is_address(value):
            raise RuntimeError(f"{CONTRACTS_ENV}={p}: {name} must be an address, got {value!r}")
        data[name] = Web3.to_checksum_address(value)
    block = data.get("deploy_block", 0)
    if not isinstance(block, int) or block < 0:
        raise RuntimeError(f"{CONTRACTS_ENV}={p}: deploy_block must be an int >= 0, got {block!r}")
    return data
