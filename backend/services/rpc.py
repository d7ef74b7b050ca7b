"""JSON-RPC over HTTP for the embedded chain, so other processes use ``Chain.rpc(<gateway>/rpc)``.

Requests go through eth-tester's own request/result formatters (the ones web3's
``EthereumTesterProvider`` applies), then results are encoded the JSON-RPC way (integers as
hex quantities). Reverts answer ``{"code": 3, "message": "execution reverted", "data": "0x.."}``
like geth/anvil, so web3 on the client raises its custom-error exception with the revert data
and ``backend.chain`` decodes it into a typed error.

Only the standard methods a client needs are served (reads, ``eth_sendRawTransaction``,
receipts, logs, chain id, gas and fees), each with its number of parameters. Nothing that
makes the node sign (``eth_sendTransaction``, ``eth_sign``) and no test or admin method
(``evm_mine``, ``evm_increaseTime``, ``evm_snapshot``, ``evm_revert``, ...): anyone can reach
``/rpc``, and those would let anyone rewrite the chain. They answer -32601 like any unknown
method. Parameters are read the execution-API way first (:mod:`backend.services.rpc_params`),
so standard clients such as Foundry's ``cast`` work unchanged.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from eth_tester.exceptions import ValidationError as TesterValidationError
from eth_utils import ValidationError as EvmValidationError
from web3.middleware import combine_middleware

from backend.chain.client import Chain
from backend.chain.rawtx import RawTx, check_chain, decode_raw_tx
from backend.services.chain import FairRLock
from backend.services.rpc_budget import GasBudget, JointBudget, Refusal
from backend.services.rpc_call import ExecutionFailed, OutOfGas, bounded_estimate, unpriced_call
from backend.services.rpc_params import InvalidParams, is_unpriced, normalize, quantity
from backend.services.rpc_results import (
    MAX_FEE_HISTORY_BLOCKS,
    MAX_REWARD_BLOCKS,
    fee_history,
    shape,
)

log = logging.getLogger(__name__)

#: Served methods -> (fewest, most) parameters.
METHODS: dict[str, tuple[int, int]] = {
    "web3_clientVersion": (0, 0),
    "net_version": (0, 0),
    "net_listening": (0, 0),
    "eth_chainId": (0, 0),
    "eth_syncing": (0, 0),
    "eth_accounts": (0, 0),
    "eth_blockNumber": (0, 0),
    "eth_gasPrice": (0, 0),
    "eth_maxPriorityFeePerGas": (0, 0),
    "eth_feeHistory": (2, 3),
    "eth_getBalance": (1, 2),
    "eth_getCode": (1, 2),
    "eth_getStorageAt": (2, 3),
    "eth_getTransactionCount": (1, 2),
    "eth_getBlockByNumber": (1, 2),
    "eth_getBlockByHash": (1, 2),
    "eth_getBlockTransactionCountByNumber": (1, 1),
    "eth_getBlockTransactionCountByHash": (1, 1),
    "eth_getTransactionByHash": (1, 1),
    "eth_getTransactionByBlockNumberAndIndex": (2, 2),
    "eth_getTransactionByBlockHashAndIndex": (2, 2),
    "eth_getTransactionReceipt": (1, 1),
    "eth_getLogs": (1, 1),
    "eth_call": (1, 4),
    "eth_estimateGas": (1, 3),
    "eth_sendRawTransaction": (1, 1),
}
ALLOWED_METHODS = frozenset(METHODS)
MAX_BATCH = 50

# JSON-RPC error codes (EIP-1474 / geth conventions).
INVALID_REQUEST = -32600
METHOD_NOT_FOUND = -32601
INVALID_PARAMS = -32602
INTERNAL_ERROR = -32603
SERVER_ERROR = -32000  # geth: e.g. "insufficient funds for gas * price + value"
LIMIT_EXCEEDED = -32005  # EIP-1474: request exceeds a defined limit (rate or gas)
UNMETERED = frozenset({"127.0.0.1", "::1", "local"})
"""Clients on this machine (the embedded platform's own workers, CLI and indexer) draw on no
budget: whoever runs there can stop the gateway anyway. The gas cap still applies."""
DEFAULT_GAS_CAP = 8_000_000
"""Most gas one ``eth_call`` / ``eth_estimateGas`` execution may use (``Settings.rpc_gas_cap``):
4x the largest platform transaction measured (an allocation among 10,000 candidates, 1.86M)."""
EXECUTION_REVERTED = 3
MAX_LOG_BLOCKS = 500
"""Most blocks one remote ``eth_getLogs`` may span: every receipt in the range is read under the
chain lock (~10 ms a block here), so the whole history of a long chain would hold it for
minutes. Providers bound it the same way (Alchemy: 2,000 blocks); the REST API's index of
events is the way to read history."""
LOG_BLOCK_GAS = 50_000
"""What reading one block's receipts costs a remote client's gas budget (``eth_getLogs``,
``eth_feeHistory`` with rewards): ~10-25 ms under the chain lock, what 30k-75k gas of execution
takes. Reads and executions hold the same lock, so they draw on the same bucket: a client
that may execute 40M gas a minute may read ~800 blocks of logs a minute, not unboundedly many
(four parallel 500-block reads held the lock 37 s in the audit of 2026-12-03)."""
HEADER_GAS = 5_000
"""What reading one block header costs (``eth_feeHistory`` without rewards: ~2 ms a block)."""


def _quantities(value: Any, key: str | None = None) -> Any:
    """Python results -> JSON-RPC encoding: ints become hex quantities (bloom: 256 bytes)."""
    if isinstance(value, bool) or value is None or isinstance(value, float | str):
        return value
    if isinstance(value, int):
        if key == "logsBloom":
            return "0x" + value.to_bytes(256, "big").hex()
        return hex(value)
    if isinstance(value, bytes):
        return "0x" + value.hex()
    if isinstance(value, dict):
        return {k: _quantities(v, k) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_quantities(v, key) for v in value]
    return value


def _revert_bytes(exc: BaseException) -> bytes | None:
    seen: BaseException | None = exc
    while seen is not None:
        for arg in seen.args:
            if isinstance(arg, bytes):
                return arg
            if isinstance(arg, BaseException):
                found = _revert_bytes(arg)
                if found is not None:
                    return found
        seen = seen.__cause__ or seen.__context__
    return None


class EmbeddedRpc:
    """Serve JSON-RPC requests (single or batch) against an embedded :class:`Chain`."""

    def __init__(
        self,
        chain: Chain,
        lock: FairRLock | threading.RLock,
        *,
        gas_cap: int = DEFAULT_GAS_CAP,
        budget: GasBudget | None = None,
        total_budget: GasBudget | None = None,
        targets: frozenset[str] = frozenset(),
    ) -> None:
        if chain._tester is None:
            raise ValueError("EmbeddedRpc serves only the embedded (eth-tester) chain")
        self.gas_cap = gas_cap
        self.budget = budget  # per remote client
        self.total_budget = total_budget  # all remote clients together (key rpc_budget.GATEWAY)
        self.targets = targets  # the platform contracts: what remote transactions may call
        self.chain = chain
        self.tester = chain._tester
        self.lock = lock
        provider = chain.w3.provider
        self._request = combine_middleware(
            middleware=provider._middleware,  # type: ignore[attr-defined]  # eth-tester's request/result formatters
            w3=chain.w3,
            provider_request_fn=provider.make_request,
        )

    def handle(self, payload: Any, client: str = "local") -> Any:
        """One JSON-RPC request object or a batch (list) from ``client`` (its key,
        ``backend.api.client_key``: the gas budget is per client, and all remote clients
        together draw on ``total_budget``). A remote client's ``eth_getLogs`` calls of one
        batch span MAX_LOG_BLOCKS blocks together, as one call may: a batch is one request."""
        log_blocks = [MAX_LOG_BLOCKS]  # what this request's eth_getLogs may still span
        if isinstance(payload, list):
            if not payload or len(payload) > MAX_BATCH:
                return _error(None, INVALID_REQUEST, f"batch must hold 1..{MAX_BATCH} requests")
            return [self._one(p, client, log_blocks) for p in payload]
        return self._one(payload, client, log_blocks)

    def _one(
        self, req: Any, client: str = "local", log_blocks: list[int] | None = None
    ) -> dict[str, Any]:
        if not isinstance(req, dict) or not isinstance(req.get("method"), str):
            return _error(None, INVALID_REQUEST, "a request is an object with a string 'method'")
        rid = req.get("id")
        method = req["method"]
        params = req.get("params", [])
        if not isinstance(params, list):
            return _error(rid, INVALID_PARAMS, "params must be a list")
        if method not in METHODS:
            return _error(rid, METHOD_NOT_FOUND, f"method {method!r} is not served here")
        fewest, most = METHODS[method]
        if not fewest <= len(params) <= most:
            return _error(
                rid, INVALID_PARAMS, f"{method} takes {fewest}..{most} params, got {len(params)}"
            )
        try:
            with self.lock:
                result = self._dispatch(method, params, client, log_blocks)
        except _RpcFailure as exc:
            return _error(rid, exc.code, exc.message, exc.data)
        except (InvalidParams, TesterValidationError) as exc:
            return _error(rid, INVALID_PARAMS, str(exc))
        except EvmValidationError as exc:  # valid request, transaction invalid on this state
            return _error(rid, SERVER_ERROR, f"invalid transaction: {exc}")
        except (OutOfGas, ExecutionFailed) as exc:
            return _error(rid, SERVER_ERROR, str(exc))
        except Exception as exc:  # eth-tester raises many types; report, never crash
            if type(exc).__name__ == "BlockNotFound":  # a block past the head: geth's answer
                return _error(rid, SERVER_ERROR, "header not found")
            data = _revert_bytes(exc)
            if type(exc).__name__ == "TransactionFailed" or data is not None:
                return _error(
                    rid, EXECUTION_REVERTED, "execution reverted", "0x" + (data or b"").hex()
                )
            # anything else is our bug or eth-tester's: its text may quote internals (paths,
            # state), so the client gets a generic answer and the log the details
            log.exception("JSON-RPC %s from %s failed unexpectedly", method, client)
            return _error(rid, INTERNAL_ERROR, "internal error")
        return {"jsonrpc": "2.0", "id": rid, "result": _quantities(result)}

    def _dispatch(
        self, method: str, params: list[Any], client: str = "local",
        log_blocks: list[int] | None = None,
    ) -> Any:
        if method == "eth_accounts":
            return []  # the node holds no keys for anyone
        params = normalize(method, params, self.chain.chain_id, self._block_number_of)
        if method in ("eth_call", "eth_estimateGas"):
            return self._execute(method, params, client)
        if method == "eth_feeHistory":
            if client not in UNMETERED:
                self._charge_reads(client, self._fee_history_cost(params))
            return fee_history(self.tester, params)
        if method == "eth_sendRawTransaction":
            tx = self._check_replay_protected(params[0])
            if client not in UNMETERED:
                self._check_remote_tx(tx, client)
        if method == "eth_getLogs":
            params[0] = self._up_to_head(params[0])
            if params[0] is None:
                return []
            if client not in UNMETERED:
                span = self._check_log_span(params[0], log_blocks or [MAX_LOG_BLOCKS])
                self._charge_reads(client, span * LOG_BLOCK_GAS)
        response = self._request(method, params)
        if "error" in response:
            err = response["error"]
            raise _RpcFailure(err.get("code", INTERNAL_ERROR), str(err.get("message", "")))
        return shape(method, response["result"])

    def _execute(self, method: str, params: list[Any], client: str) -> Any:
        """``eth_call`` / ``eth_estimateGas``: bounded by the gas cap and the client's budget.

        A priced call (fee fields given) must be affordable by its sender, as on geth; the
        execution itself is then unpriced, like the unpriced ones (fees change no gas used).
        """
        tx, block = params[0], params[1]
        if not is_unpriced(tx):
            self._check_affordable(tx, block)
        budget = None if client in UNMETERED else self.joint_budget()
        if budget is not None:
            refused = budget.shortfall(client, self.gas_cap)
            if refused is not None:
                raise _gas_used_up(refused)

        def charge(gas: int) -> None:
            if budget is not None:
                budget.charge(client, gas)

        if method == "eth_estimateGas":
            return bounded_estimate(self.tester, tx, block, gas_cap=self.gas_cap, charge=charge)
        try:
            done = unpriced_call(self.tester, tx, block, gas_cap=self.gas_cap)
        except OutOfGas as exc:
            charge(exc.gas)
            raise
        charge(done.gas_used)
        return done.output

    def _check_affordable(self, tx: dict[str, Any], block: int | str) -> None:
        price = max(int(tx.get(k, 0)) for k in ("gasPrice", "maxFeePerGas"))
        need = min(int(tx.get("gas", self.gas_cap)), self.gas_cap) * price + int(tx.get("value", 0))
        have = int(self.tester.get_balance(tx["from"], block))
        if need > have:
            raise _RpcFailure(
                SERVER_ERROR,
                f"insufficient funds for gas * price + value: have {have} want {need}",
            )

    def _check_replay_protected(self, raw: Any) -> RawTx:
        """A raw transaction signed for this chain (EIP-155), as geth requires over RPC."""
        if not isinstance(raw, str) or not raw.startswith("0x"):
            raise InvalidParams("the transaction must be hex bytes ('0x...')")
        try:
            tx = decode_raw_tx(bytes.fromhex(raw[2:]))
            check_chain(tx, self.chain.chain_id)
        except ValueError as exc:  # RawTxError, or hex that does not parse
            raise _RpcFailure(SERVER_ERROR, f"invalid transaction: {exc}") from None
        return tx

    def _check_remote_tx(self, tx: RawTx, client: str) -> None:
        """What a remote client may have mined: calls of the platform contracts and plain
        transfers, with at most the gas cap, drawn from its gas budget. A transaction holds
        the chain lock while it runs (a 30M-gas loop: ~7 s), and the faucet pays its fee, so
        arbitrary code (a contract it deployed) would let anyone stop the platform."""
        if tx.to is None:
            raise _RpcFailure(
                SERVER_ERROR, "contract creation is not accepted from remote clients here"
            )
        plain_transfer = not tx.data and self.tester.get_code(tx.to) in ("0x", b"")
        if tx.to not in self.targets and not plain_transfer:
            raise _RpcFailure(
                SERVER_ERROR,
                f"transaction goes to {tx.to}: remote clients may call the platform contracts "
                f"({', '.join(sorted(self.targets))}) or send plain transfers",
            )
        if tx.gas > self.gas_cap:
            raise _RpcFailure(
                SERVER_ERROR, f"gas limit {tx.gas} is over this gateway's cap of {self.gas_cap}"
            )
        refused = self.joint_budget().take(client, tx.gas)
        if refused is not None:
            raise _gas_used_up(refused)

    def _charge_reads(self, client: str, gas: int) -> None:
        """Draw what a read will hold the chain lock for from the client's gas budget, before
        reading (-32005 with the seconds to wait when the bucket does not hold it)."""
        if gas > 0:
            refused = self.joint_budget().take(client, gas)
            if refused is not None:
                raise _gas_used_up(refused)

    def joint_budget(self) -> JointBudget:
        """The client's bucket and the gateway-wide one (read at each call: both are
        attributes a test or the route may set after construction)."""
        return JointBudget(self.budget, self.total_budget)

    @staticmethod
    def _fee_history_cost(params: list[Any]) -> int:
        """Gas-equivalent of an ``eth_feeHistory`` read (0 when its block count is invalid:
        :func:`fee_history` refuses it without reading)."""
        try:
            count = quantity(params[0], "blockCount")
        except InvalidParams:
            return 0
        rewards = len(params) > 2 and params[2] is not None
        if not 1 <= count <= (MAX_REWARD_BLOCKS if rewards else MAX_FEE_HISTORY_BLOCKS):
            return 0
        return count * (LOG_BLOCK_GAS if rewards else HEADER_GAS)

    def _check_log_span(self, flt: dict[str, Any], left: list[int]) -> int:
        """Refuse a filter spanning more blocks than ``left[0]`` (the request's remaining span
        of MAX_LOG_BLOCKS); take its span off otherwise and return it."""
        head = int(self.tester.get_block_by_number("latest")["number"])

        def number(at: Any) -> int:
            return 0 if at == "earliest" else at if isinstance(at, int) else head

        start, end = number(flt.get("fromBlock", "latest")), number(flt.get("toBlock", "latest"))
        span = max(end - start + 1, 1)
        if span > left[0]:
            raise _RpcFailure(
                LIMIT_EXCEEDED,
                f"eth_getLogs spans {span} blocks; at most {MAX_LOG_BLOCKS} per request "
                f"(a batch's calls together; {left[0]} left) from remote clients (read history "
                "from the REST API's index)",
            )
        left[0] -= span
        return span

    def _up_to_head(self, flt: dict[str, Any]) -> dict[str, Any] | None:
        """A log filter with block numbers past the head clamped to it (geth's rule); None if
        it starts past the head (no logs)."""
        head = int(self.tester.get_block_by_number("latest")["number"])
        start, end = flt.get("fromBlock"), flt.get("toBlock")
        if isinstance(start, int) and start > head:
            return None
        if isinstance(end, int) and end > head:
            flt = {**flt, "toBlock": head}
        return flt

    def _block_number_of(self, block_hash: str) -> int:
        try:
            return int(self.tester.get_block_by_hash(block_hash)["number"])
        except Exception:  # eth-tester: BlockNotFound
            raise InvalidParams(f"no block with hash {block_hash}") from None


class _RpcFailure(Exception):
    def __init__(self, code: int, message: str, data: str | None = None) -> None:
        super().__init__(message)
        self.code, self.message, self.data = code, message, data


def _gas_used_up(refused: Refusal) -> _RpcFailure:
    if refused.bucket == "gateway":
        return _RpcFailure(
            LIMIT_EXCEEDED,
            f"gateway-wide execution gas of all remote clients used up ({refused.per_minute} "
            f"gas a minute together, block reads included): retry in {refused.wait_s} s",
        )
    return _RpcFailure(
        LIMIT_EXCEEDED,
        f"execution gas of this client used up ({refused.per_minute} gas a minute, block reads "
        f"included): retry in {refused.wait_s} s",
    )


def _error(rid: Any, code: int, message: str, data: str | None = None) -> dict[str, Any]:
    err: dict[str, Any] = {"code": code, "message": message}
    if data is not None:
        err["data"] = data
    return {"jsonrpc": "2.0", "id": rid, "error": err}
