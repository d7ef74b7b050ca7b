"""One chain interface, two backends: embedded eth-tester (py-evm) and a JSON-RPC endpoint.

Every state change goes build -> sign locally -> send raw -> wait for receipt (STYLE.md,
web3.py section); the node never signs. Reverts surface as typed
:class:`backend.chain.errors.ContractError` subclasses with decoded arguments, raised from
the gas estimate (or a replayed call when a mined transaction failed).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import threading
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import requests
from eth_abi.codec import ABICodec
from eth_abi.decoding import StringDecoder
from eth_abi.registry import BaseEquals
from eth_account import Account
from eth_account.signers.local import LocalAccount
from eth_utils import keccak
from web3 import Web3
from web3._utils.events import get_event_data
from web3.contract import Contract
from web3.exceptions import ContractCustomError, ContractLogicError

from ..httpbounds import (
    ERROR_BODY_BYTES,
    Budget,
    ResponseRefused,
    refuse_encoding,
    without_userinfo,
)
from ..settings import ChainClientSettings, load_chain_client_settings
from . import errors
from .artifacts import load_artifact
from .pyevm import restore_recursion_limit
from .tx_lookup import use_indexed_lookup

try:  # eth-tester raises its own exception type for reverts
    from eth_tester.exceptions import TransactionFailed as _TesterFailed
except ImportError:  # pragma: no cover - eth-tester is a dependency
    _TesterFailed = ContractLogicError
restore_recursion_limit()  # eth_account and py-evm raised it at import

_REVERTS = (ContractCustomError, ContractLogicError, _TesterFailed)
_DECODE_SLIPS = (OverflowError, ValueError, TypeError)
"""What web3's eth-tester provider can raise *while* turning a revert into its own exception:
it reads every revert as ``Error(string)``, so a custom error whose first word points inside
the data at a word >= 2**63 (``TasksBadDuration(60, 660, 2592000)``: offset 60, "length"
0x294 << 224 ...) makes eth_abi raise ``OverflowError``, not its ``DecodingError``. The revert
is still in the exception's context (:func:`_slipped_revert`)."""


class _ReplacingStringDecoder(StringDecoder):
    """An event's ``string`` with bytes that are not UTF-8 replaced by U+FFFD."""

    def __init__(self) -> None:
        super().__init__(handle_string_errors="replace")


def _lenient_strings(codec: ABICodec) -> ABICodec:
    """``codec`` decoding strings leniently, for event logs: the contracts take any bytes as a
    string (a task or model description in anyone's own transaction), and eth_abi's strict
    UTF-8 made such a log raise, so the indexer stopped at its block for good and never indexed
    the events after it. Every other type decodes exactly as in ``codec``."""
    registry = codec._registry.copy()
    registry.unregister_decoder("string")
    registry.register_decoder(BaseEquals("string"), _ReplacingStringDecoder, label="string")
    return ABICodec(registry)


# anvil's and hardhat's well-known development mnemonic (never use it outside tests).
DEV_MNEMONIC = "test test test test test test test test test test test junk"
GAS_MARGIN = 1.2  # headroom over eth_estimateGas: block timestamp may move between the two


class NodeRefused(RuntimeError):
    """The JSON-RPC node asked for something the client does not sign (another chain id than
    the pinned one, a fee or gas above the caps): nothing was signed."""


class _BoundedSession(requests.Session):
    """The ``requests`` session of a JSON-RPC provider: redirects are refused, not followed
    (R9), compressed answers too, and each answer is read within ``max_bytes`` and
    ``deadline_s`` of its headers (:mod:`backend.httpbounds`); of an error, 64 KiB."""

    def __init__(self, max_bytes: int, deadline_s: float) -> None:
        super().__init__()  # (max_redirects = 0 would raise TooManyRedirects: less clear)
        self.headers["Accept-Encoding"] = "identity"
        self.max_bytes = max_bytes
        self.deadline_s = deadline_s

    def request(self, method: str | bytes, url: str | bytes, *args: Any, **kwargs: Any) -> Any:
        kwargs["allow_redirects"] = False
        kwargs["stream"] = True
        response = super().request(method, url, *args, **kwargs)
        where = url.decode() if isinstance(url, bytes) else str(url)
        try:
            if 300 <= response.status_code < 400:
                raise ResponseRefused(
                    where,
                    f"it redirects (HTTP {response.status_code}) to "
                    f"{response.headers.get('location')!r}; a JSON-RPC node's redirects are not "
                    "followed",
                )
            reason = refuse_encoding(where, response.headers.get("content-encoding"))
            if reason is not None:
                raise ResponseRefused(where, reason)
            raw = response.raw.stream(2**16, decode_content=False)
            if response.ok:
                budget = Budget(where, self.max_bytes, self.deadline_s)
                budget.declared(response.headers.get("content-length"))
                body = budget.read(raw)
            else:  # its start is enough to report it
                budget = Budget(where, None, self.deadline_s)
                body = b""
                for chunk in raw:
                    budget.take(len(chunk))
                    body += chunk
                    if len(body) >= ERROR_BODY_BYTES:
                        body = body[:ERROR_BODY_BYTES]
                        break
        except BaseException:
            response.close()
            raise
        response._content = body
        response._content_consumed = True
        response.close()
        return response


def _deployment_chain_id() -> int | None:
    """The ``chain_id`` of the ``DRLAAS_CONTRACTS`` deployment (JSON or a file), if it names
    one; a missing or unreadable one is reported by whoever attaches with it."""
    env = os.environ.get("DRLAAS_CONTRACTS", "").strip()
    if not env:
        return None
    try:
        doc = json.loads(env if env.startswith("{") else Path(env).read_text())
    except (OSError, ValueError):
        return None
    value = doc.get("chain_id") if isinstance(doc, dict) else None
    if isinstance(value, int) and not isinstance(value, bool) and value > 0:
        return value
    return None


def pinned_chain_id(limits: ChainClientSettings) -> tuple[int | None, str]:
    """(the chain id a JSON-RPC client must find, where the pin comes from); ``None`` when
    none is known: ``DRLAAS_CHAIN_ID``, else the ``DRLAAS_CONTRACTS`` deployment's."""
    if limits.chain_id is not None:
        return limits.chain_id, "DRLAAS_CHAIN_ID"
    deployed = _deployment_chain_id()
    if deployed is not None:
        return deployed, "the DRLAAS_CONTRACTS deployment"
    return None, ""


@dataclasses.dataclass
class Event:
    """A decoded log: ``contract`` and ``name`` of the event, ``args`` by parameter name."""

    contract: str
    name: str
    args: dict[str, Any]
    address: str
    log_index: int


@dataclasses.dataclass
class Receipt:
    """The parts of a transaction receipt the platform uses, with decoded events."""

    tx_hash: str
    status: int
    gas_used: int
    effective_gas_price: int
    block_number: int
    events: list[Event]
    calldata: bytes = dataclasses.field(default=b"", repr=False)
    contract_address: str | None = None

    @property
    def fee(self) -> int:
        """Native currency paid for gas (0 on the consortium chain; base fee on eth-tester)."""
        return self.gas_used * self.effective_gas_price

    def named(self, name: str) -> list[Event]:
        """The events of this receipt called ``name`` (in log order)."""
        return [e for e in self.events if e.name == name]

    def one(self, name: str) -> Event:
        """The single event called ``name``; AssertionError if there are 0 or several."""
        found = self.named(name)
        if len(found) != 1:
            raise AssertionError(f"expected one {name} event, got {len(found)}: {self.events}")
        return found[0]


ESTIMATE_AT = "pending"
"""Block a transaction's gas is estimated at on a JSON-RPC node: the pending block, where a
transaction sent now runs (``block.number`` one past the head on anvil, geth and the gateway's
``/rpc``; the head on Besu), so a reveal sent right after its commitment's receipt estimates as
it will execute. The in-process eth-tester estimates there by default (and takes no block)."""


class ContractHandle:
    """A deployed contract: ``call`` for views, ``transact`` for state changes."""

    def __init__(self, chain: Chain, name: str, contract: Contract):
        self.chain = chain
        self.name = name
        self.contract = contract
        self.address: str = contract.address

    def call(self, fn: str, *args: Any, sender: str | None = None) -> Any:
        """Run view/pure function ``fn`` (or simulate a state change) and return its result."""
        return self.chain.call(self.contract, fn, *args, sender=sender)

    def transact(self, fn: str, *args: Any, sender: str, value: int = 0) -> Receipt:
        """Send a signed transaction calling ``fn``; returns the mined receipt."""
        return self.chain.transact(self.contract, fn, *args, sender=sender, value=value)

    def estimate(self, fn: str, *args: Any, sender: str | None = None, value: int = 0) -> int:
        """eth_estimateGas of ``fn`` (used for view functions in the gas report)."""
        f = self.contract.functions[fn](*args)
        with _typed_reverts():
            return f.estimate_gas(
                {"from": sender or self.chain.accounts[0], "value": value},
                block_identifier=self.chain.estimate_at,
            )

    def __repr__(self) -> str:
        return f"<{self.name} at {self.address}>"


def _revert_data(exc: BaseException) -> bytes | str | None:
    """Raw revert data from web3's exception, or from eth-tester's chained one."""
    seen: BaseException | None = exc
    while seen is not None:
        data = getattr(seen, "data", None)
        if isinstance(data, dict):  # some providers wrap it
            data = data.get("data")
        if isinstance(data, str | bytes) and data:
            return data
        if seen.args and isinstance(seen.args[0], bytes):
            return seen.args[0]
        seen = seen.__cause__ or seen.__context__
    return None


def typed_revert(exc: BaseException) -> errors.ContractError:
    """The revert that ``exc`` (web3, eth-tester or a node) carries, as a typed contract error
    (:class:`errors.UnknownRevert` when it carries no known error)."""
    return errors.decode_revert(_revert_data(exc))


def _slipped_revert(exc: BaseException) -> bool:
    """``exc`` (one of :data:`_DECODE_SLIPS`) was raised while a revert was being reported:
    a revert exception is in its cause/context chain."""
    seen = exc.__cause__ or exc.__context__
    for _ in range(8):
        if seen is None:
            return False
        if isinstance(seen, _REVERTS):
            return True
        seen = seen.__cause__ or seen.__context__
    return False


@contextlib.contextmanager
def _typed_reverts() -> Iterator[None]:
    """Reverts inside the block raise the typed :class:`errors.ContractError`; so does a
    revert web3 failed to report (:data:`_DECODE_SLIPS`). Anything else goes through."""
    try:
        yield
    except _REVERTS as exc:
        raise typed_revert(exc) from None
    except _DECODE_SLIPS as exc:
        if not _slipped_revert(exc):
            raise
        raise typed_revert(exc) from None


class Chain:
    """A web3 connection plus local signing keys; see :meth:`embedded` and :meth:`rpc`."""

    def __init__(
        self,
        w3: Web3,
        keys: Iterable[LocalAccount],
        kind: str,
        tester: Any = None,
        *,
        limits: ChainClientSettings | None = None,
    ):
        self.w3 = w3
        # caps on what a node may ask us to sign (None: the in-process chain, no node)
        self.limits = limits
        self.kind = kind
        self._tester = tester
        self._keys = {a.address: a for a in keys}
        self.accounts: list[str] = list(self._keys)
        self.chain_id: int = w3.eth.chain_id
        self._log_codec = _lenient_strings(w3.codec)
        self._by_address: dict[str, tuple[str, Contract]] = {}
        # (contract address, topic0) -> (contract name, event ABI): two contracts may share
        # an event signature (PaymentCredited in TMC and MMC).
        self._topics: dict[tuple[str, bytes], tuple[str, dict[str, Any]]] = {}
        self.fees_paid = 0  # native currency spent on gas by transactions sent through us
        # nonce read -> send is one step per process: a second thread sending for the same key
        # (the worker daemon's recovery retries beside its job) would otherwise reuse a nonce
        self._send_lock = threading.Lock()
        self.estimate_at: str | None = None if tester is not None else ESTIMATE_AT

    # -- construction -------------------------------------------------------------------
    @classmethod
    def embedded(cls, accounts: int = 10, directory: str | Path | None = None) -> Chain:
        """An in-process py-evm chain with ``accounts`` funded accounts (1,000,000 ETH each).

        With ``directory`` the chain lives on disk there (:mod:`backend.chain.durable`) and a
        later call with the same directory reopens it; without, it lives in memory (tests)."""
        from eth_tester import EthereumTester, PyEVMBackend
        from web3 import EthereumTesterProvider

        restore_recursion_limit()
        use_indexed_lookup()

        if accounts < 1:
            raise ValueError(f"accounts must be >= 1, got {accounts}")
        if directory is not None:
            from .durable import DurableBackend

            backend: PyEVMBackend = DurableBackend(directory, accounts)
        else:
            backend = PyEVMBackend(
                genesis_state=PyEVMBackend.generate_genesis_state(num_accounts=accounts)
            )
        tester = EthereumTester(backend)
        w3 = Web3(EthereumTesterProvider(tester))
        keys = [Account.from_key(k.to_bytes()) for k in backend.account_keys]
        return cls(w3, keys, "embedded", tester)

    @classmethod
    def rpc(
        cls,
        url: str,
        private_keys: Iterable[str] | None = None,
        n_dev_accounts: int = 10,
        *,
        chain_id: int | None = None,
        limits: ChainClientSettings | None = None,
    ) -> Chain:
        """A JSON-RPC node at ``url``; signs with ``private_keys`` (default: the dev mnemonic,
        which anvil funds).

        The node is not trusted (docs/platform.md, "Clients against hostile servers"):
        its answers are bounded (``limits``, default from the ``DRLAAS_*`` environment:
        :class:`~backend.settings.ChainClientSettings`), its redirects refused, and it must
        report the chain id of :func:`pinned_chain_id` and ``chain_id``, each if known, else
        :class:`NodeRefused`; fees and gas above the caps are refused when signing."""
        limits = limits if limits is not None else load_chain_client_settings()
        session = _BoundedSession(limits.chain_max_response_bytes, 2 * limits.chain_timeout_s)
        provider = Web3.HTTPProvider(
            url, request_kwargs={"timeout": limits.chain_timeout_s}, session=session
        )
        w3 = Web3(provider)
        if not w3.is_connected():
            raise ConnectionError(f"no JSON-RPC node answers at {without_userinfo(url)}")
        if private_keys is None:
            Account.enable_unaudited_hdwallet_features()
            keys = [
                Account.from_mnemonic(DEV_MNEMONIC, account_path=f"m/44'/60'/0'/0/{i}")
                for i in range(n_dev_accounts)
            ]
        else:
            keys = [Account.from_key(k) for k in private_keys]
        chain = cls(w3, keys, "rpc", limits=limits)
        for expected, source in (pinned_chain_id(limits), (chain_id, "the caller")):
            if expected is not None and chain.chain_id != expected:  # every pin must hold
                raise NodeRefused(
                    f"the JSON-RPC node at {without_userinfo(url)} reports chain id "
                    f"{chain.chain_id}, but {source} pins chain id {expected}: refusing to sign "
                    "for another chain (wrong node, or a hostile one)"
                )
        return chain

    # -- contracts ----------------------------------------------------------------------
    def register(self, name: str, address: str) -> ContractHandle:
        """A handle on contract ``name`` (artifact) already deployed at ``address``."""
        abi = load_artifact(name)["abi"]
        contract = self.w3.eth.contract(address=Web3.to_checksum_address(address), abi=abi)
        self._by_address[contract.address] = (name, contract)
        for item in abi:
            if item.get("type") == "event":
                types = ",".join(errors._canonical(i) for i in item["inputs"])
                topic = keccak(text=f"{item['name']}({types})")
                self._topics[(contract.address, topic)] = (name, item)
        return ContractHandle(self, name, contract)

    def deploy(self, name: str, *args: Any, sender: str) -> tuple[ContractHandle, Receipt]:
        """Deploy artifact ``name`` with constructor ``args``; returns (handle, receipt)."""
        art = load_artifact(name)
        factory = self.w3.eth.contract(abi=art["abi"], bytecode=art["bytecode"])
        receipt = self._send(factory.constructor(*args), sender, 0)
        return self.register(name, receipt.contract_address), receipt

    # -- calls and transactions ---------------------------------------------------------
    def call(self, contract: Contract, fn: str, *args: Any, sender: str | None = None) -> Any:
        """Execute ``fn`` without a transaction; custom errors raise typed exceptions."""
        with _typed_reverts():
            return contract.functions[fn](*args).call({"from": sender or self.accounts[0]})

    def transact(
        self, contract: Contract, fn: str, *args: Any, sender: str, value: int = 0
    ) -> Receipt:
        """Build, sign locally, send raw and wait for the receipt of ``fn(*args)``."""
        return self._send(contract.functions[fn](*args), sender, value)

    def _send(self, fn: Any, sender: str, value: int) -> Receipt:
        if sender not in self._keys:
            raise KeyError(f"no signing key for sender {sender}; known: {self.accounts}")
        with self._send_lock:
            tx, tx_hash = self._sign_and_send(fn, sender, value)
        raw = self.w3.eth.wait_for_transaction_receipt(tx_hash, timeout=120)
        receipt = Receipt(
            tx_hash="0x" + bytes(tx_hash).hex(),
            status=raw["status"],
            gas_used=raw["gasUsed"],
            effective_gas_price=raw.get("effectiveGasPrice", 0) or 0,
            block_number=raw["blockNumber"],
            calldata=bytes.fromhex(tx["data"][2:]) if tx.get("data") else b"",
            events=self._decode_logs(raw["logs"]),
            contract_address=raw.get("contractAddress"),
        )
        self.fees_paid += receipt.fee
        if receipt.status != 1:
            # Replay as a call at the parent block to recover the revert data.
            with _typed_reverts():
                fn.call({"from": sender, "value": value}, block_identifier=raw["blockNumber"] - 1)
            raise errors.UnknownRevert({"tx": receipt.tx_hash})
        return receipt

    def _sign_and_send(self, fn: Any, sender: str, value: int) -> tuple[dict[str, Any], Any]:
        """Build ``fn``'s transaction at the sender's next nonce, sign it and send it raw;
        (the transaction, its hash). Called under ``_send_lock``."""
        limits = self.limits
        max_fee = limits.tx_max_fee_per_gas_wei if limits is not None else None
        max_gas = limits.tx_max_gas if limits is not None else 30_000_000
        base = self.w3.eth.get_block("latest").get("baseFeePerGas")
        params: dict[str, Any] = {
            "from": sender,
            "value": value,
            "nonce": self.w3.eth.get_transaction_count(sender, "pending"),
            "chainId": self.chain_id,
        }
        if base is None:  # pre-London PoA chains (e.g. some Quorum/Besu setups): legacy tx
            price = self.w3.eth.gas_price
            params["gasPrice"] = self._checked_fee("gas price (eth_gasPrice)", price)
        else:
            params["maxPriorityFeePerGas"] = 0  # consortium chain: no tips
            base = self._checked_fee("base fee of the latest block", base)
            params["maxFeePerGas"] = 2 * base if max_fee is None else min(2 * base, max_fee)
        with _typed_reverts():
            gas = fn.estimate_gas(
                {k: params[k] for k in ("from", "value")}, block_identifier=self.estimate_at
            )
        if limits is not None and int(gas) > max_gas:
            raise NodeRefused(
                f"the node estimates {int(gas)} gas for this transaction, above the cap of "
                f"{max_gas} (DRLAAS_TX_MAX_GAS): not signed"
            )
        params["gas"] = min(int(gas * GAS_MARGIN) + 10_000, max_gas)
        tx = fn.build_transaction(params)
        signed = self._keys[sender].sign_transaction(tx)
        tx_hash = self.w3.eth.send_raw_transaction(signed.raw_transaction)
        return tx, tx_hash

    def _checked_fee(self, what: str, wei: Any) -> int:
        """``wei`` (a node's gas price or base fee), refused above ``tx_max_fee_per_gas_wei``."""
        wei = int(wei)
        cap = self.limits.tx_max_fee_per_gas_wei if self.limits is not None else None
        if wei < 0 or (cap is not None and wei > cap):
            raise NodeRefused(
                f"the node reports a {what} of {wei} wei, above the cap of {cap} wei "
                "(DRLAAS_TX_MAX_FEE_PER_GAS_WEI): not signed"
            )
        return wei

    def _decode_logs(self, logs: list[Any]) -> list[Event]:
        out = []
        for log in logs:
            topics = log["topics"]
            address = Web3.to_checksum_address(log["address"])
            hit = self._topics.get((address, bytes(topics[0]))) if topics else None
            if hit is None:
                continue
            cname, abi = hit
            data = get_event_data(self._log_codec, abi, log)
            out.append(
                Event(cname, data["event"], dict(data["args"]), log["address"], log["logIndex"])
            )
        return out

    def logs(
        self, handle: ContractHandle, from_block: int = 0, topics: list[Any] | None = None
    ) -> list[Event]:
        """Every decoded event emitted by ``handle`` since ``from_block`` (indexer input), or
        only those matching ``topics`` (an eth_getLogs topic filter)."""
        query: dict[str, Any] = {"address": handle.address, "fromBlock": from_block,
                                 "toBlock": "latest"}
        if topics is not None:
            query["topics"] = topics
        return self._decode_logs(self.w3.eth.get_logs(query))

    def vm_name(self) -> str:
        """The EVM fork in use ("PragueVM" on eth-tester; the node's client on RPC)."""
        if self._tester is not None:
            return type(self._tester.backend.chain.get_vm()).__name__
        return str(self.w3.client_version)

    # -- chain state --------------------------------------------------------------------
    @property
    def genesis_hash(self) -> str:
        """Hash of block 0: tells one chain from another (a reset dev node, a new embedded
        directory), whatever their chain ids."""
        return "0x" + bytes(self.w3.eth.get_block(0)["hash"]).hex()

    def close(self) -> None:
        """Release the embedded chain's file (every mined block is already on disk)."""
        kv = getattr(getattr(self._tester, "backend", None), "kv", None)
        if kv is not None:
            kv.close()

    def balance(self, address: str) -> int:
        return self.w3.eth.get_balance(address)

    def now(self) -> int:
        """Timestamp of the latest block (what ``block.timestamp`` was last)."""
        return self.w3.eth.get_block("latest")["timestamp"]

    def advance_time(self, seconds: int) -> int:
        """Move chain time forward by ``seconds`` and mine a block; returns the new time."""
        if seconds <= 0:
            raise ValueError(f"seconds must be positive, got {seconds}")
        target = self.now() + seconds
        if self._tester is not None:
            self._tester.time_travel(target)
        else:
            self.w3.provider.make_request("evm_increaseTime", [seconds])
            self.w3.provider.make_request("evm_mine", [])
        return self.now()

    def await_block_after(self, number: int, timeout: float = 60.0) -> int:
        """Return once a transaction sent now runs in a block after ``number``; the number of
        the block it would run in. What a reveal waits for after its commitment was mined in
        ``number`` (TMC.commitCid takes it only in a later block). A node that builds a
        pending block on its head (eth-tester, anvil, geth) answers at once, and transactions
        are estimated there (:data:`ESTIMATE_AT`); one whose pending block is its head (Besu)
        is polled until its next block (a QBFT block period)."""
        deadline = time.monotonic() + timeout
        while True:
            pending = self.w3.eth.get_block("pending").get("number")
            if pending is None:  # a node without a pending block: its head, executed there
                pending = self.w3.eth.block_number
            if int(pending) > number:
                return int(pending)
            if time.monotonic() > deadline:
                raise TimeoutError(f"no block after {number} within {timeout:.0f} s")
            time.sleep(0.2)

    def snapshot(self) -> Any:
        """A snapshot id for :meth:`revert` (test isolation)."""
        if self._tester is not None:
            return self._tester.take_snapshot()
        return self.w3.provider.make_request("evm_snapshot", [])["result"]

    def revert(self, snapshot_id: Any) -> None:
        if self._tester is not None:
            self._tester.revert_to_snapshot(snapshot_id)
        else:
            self.w3.provider.make_request("evm_revert", [snapshot_id])
