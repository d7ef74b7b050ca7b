"""JSON-RPC over HTTP for the embedded chain, so other processes use ``Chain.rpc(<gateway>/rpc)``.

Requests go through eth-tester's own request/result formatters (the ones web3's
``EthereumTesterProvider`` applies), then results are encoded the JSON-RPC way (integers as
hex quantities). Reverts answer ``{"code": 3, "message": "execution reverted", "data": "0x.."}``
like geth/anvil, so web3 on the client raises its custom-error exception with the revert data
and ``backend.chain`` decodes it into a typed error.

Only a whitelist of methods is served: nothing that makes the node sign (``eth_sendTransaction``,
``eth_sign``) — every write is a locally signed raw transaction.
"""

from __future__ import annotations

import threading
from typing import Any

from web3.middleware import combine_middleware

from backend.chain.client import Chain

ALLOWED_METHODS = frozenset(
    {
        "web3_clientVersion",
        "net_version",
        "net_listening",
        "eth_chainId",
        "eth_blockNumber",
        "eth_getBalance",
        "eth_getCode",
        "eth_getStorageAt",
        "eth_getTransactionCount",
        "eth_getBlockByNumber",
        "eth_getBlockByHash",
        "eth_getTransactionByHash",
        "eth_getTransactionReceipt",
        "eth_getLogs",
        "eth_call",
        "eth_estimateGas",
        "eth_gasPrice",
        "eth_maxPriorityFeePerGas",
        "eth_feeHistory",
        "eth_sendRawTransaction",
        "eth_syncing",
        "eth_accounts",
        "evm_mine",
        "evm_increaseTime",
        "evm_snapshot",
        "evm_revert",
    }
)
MAX_BATCH = 50

# JSON-RPC error codes (EIP-1474 / geth conventions).
INVALID_REQUEST = -32600
METHOD_NOT_FOUND = -32601
INVALID_PARAMS = -32602
INTERNAL_ERROR = -32603
EXECUTION_REVERTED = 3


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

    def __init__(self, chain: Chain, lock: threading.RLock) -> None:
        if chain._tester is None:
            raise ValueError("EmbeddedRpc serves only the embedded (eth-tester) chain")
        self.chain = chain
        self.tester = chain._tester
        self.lock = lock
        provider = chain.w3.provider
        self._request = combine_middleware(
            middleware=provider._middleware,  # type: ignore[attr-defined]  # eth-tester's request/result formatters
            w3=chain.w3,
            provider_request_fn=provider.make_request,
        )

    def handle(self, payload: Any) -> Any:
        """One JSON-RPC request object or a batch (list); returns the response(s)."""
        if isinstance(payload, list):
            if not payload or len(payload) > MAX_BATCH:
                return _error(None, INVALID_REQUEST, f"batch must hold 1..{MAX_BATCH} requests")
            return [self._one(p) for p in payload]
        return self._one(payload)

    def _one(self, req: Any) -> dict[str, Any]:
        if not isinstance(req, dict) or not isinstance(req.get("method"), str):
            return _error(None, INVALID_REQUEST, "a request is an object with a string 'method'")
        rid = req.get("id")
        method = req["method"]
        params = req.get("params", [])
        if not isinstance(params, list):
            return _error(rid, INVALID_PARAMS, "params must be a list")
        if method not in ALLOWED_METHODS:
            return _error(rid, METHOD_NOT_FOUND, f"method {method!r} is not served here")
        try:
            with self.lock:
                result = self._dispatch(method, params)
        except _RpcFailure as exc:
            return _error(rid, exc.code, exc.message, exc.data)
        except Exception as exc:  # eth-tester raises many types; report, never crash
            data = _revert_bytes(exc)
            if type(exc).__name__ == "TransactionFailed" or data is not None:
                return _error(
                    rid, EXECUTION_REVERTED, "execution reverted", "0x" + (data or b"").hex()
                )
            return _error(rid, INTERNAL_ERROR, f"{type(exc).__name__}: {exc}")
        return {"jsonrpc": "2.0", "id": rid, "result": _quantities(result)}

    def _dispatch(self, method: str, params: list[Any]) -> Any:
        t = self.tester
        if method == "eth_accounts":
            return []  # the node holds no keys for anyone
        if method == "evm_mine":
            t.mine_blocks(1)
            return "0x0"
        if method == "evm_increaseTime":
            seconds = _int_param(params, 0, "seconds")
            if seconds <= 0:
                raise _RpcFailure(INVALID_PARAMS, "seconds must be positive")
            now = t.get_block_by_number("pending")["timestamp"]
            t.time_travel(now + seconds)
            return seconds
        if method == "evm_snapshot":
            return t.take_snapshot()
        if method == "evm_revert":
            t.revert_to_snapshot(_int_param(params, 0, "snapshot id"))
            return True
        response = self._request(method, params)
        if "error" in response:
            err = response["error"]
            raise _RpcFailure(err.get("code", INTERNAL_ERROR), str(err.get("message", "")))
        return response["result"]


class _RpcFailure(Exception):
    def __init__(self, code: int, message: str, data: str | None = None) -> None:
        super().__init__(message)
        self.code, self.message, self.data = code, message, data


def _int_param(params: list[Any], i: int, name: str) -> int:
    try:
        v = params[i]
        return int(v, 16) if isinstance(v, str) else int(v)
    except (IndexError, TypeError, ValueError):
        raise _RpcFailure(INVALID_PARAMS, f"param {i} ({name}) must be an integer") from None


def _error(rid: Any, code: int, message: str, data: str | None = None) -> dict[str, Any]:
    err: dict[str, Any] = {"code": code, "message": message}
    if data is not None:
        err["data"] = data
    return {"jsonrpc": "2.0", "id": rid, "error": err}
