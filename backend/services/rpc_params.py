"""Execution-API request parameters -> the forms eth-tester takes (``/rpc``, EmbeddedRpc).

Standard clients (Foundry's ``cast``, ethers, viem, web3.py) send what the Ethereum
execution-API spec defines: call objects with ``input`` (the newer name of ``data``),
``chainId``, ``type``, ``nonce``; block parameters as tags, hex numbers or EIP-1898 objects;
log filters with ``blockHash``. eth-tester accepts a narrower set and raises on the rest, so
each request is checked and rewritten here first. A malformed parameter raises
:class:`InvalidParams` naming it (JSON-RPC -32602).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

ZERO_ADDRESS = "0x" + "00" * 20
BLOCK_TAGS = frozenset({"latest", "earliest", "pending", "safe", "finalized"})
FEE_FIELDS = ("gasPrice", "maxFeePerGas", "maxPriorityFeePerGas")
CALL_FIELDS = frozenset(
    {
        "from",
        "to",
        "gas",
        "value",
        "input",
        "data",
        "nonce",
        "chainId",
        "type",
        "accessList",
        "authorizationList",
        *FEE_FIELDS,
    }
)
BLOB_FIELDS = frozenset({"blobVersionedHashes", "maxFeePerBlobGas", "blobs"})
SERVED_TX_TYPES = frozenset({0, 1, 2, 4})  # legacy, access list, EIP-1559, EIP-7702
FILTER_FIELDS = frozenset({"fromBlock", "toBlock", "address", "topics", "blockHash"})
_QUANTITY = re.compile(r"0x[0-9a-fA-F]{1,64}")
_HASH = re.compile(r"0x[0-9a-fA-F]{64}")
_ADDRESS = re.compile(r"0x[0-9a-fA-F]{40}")
_DATA = re.compile(r"0x(?:[0-9a-fA-F]{2})*")

#: Position of the block parameter for the methods that take one.
BLOCK_PARAM = {
    "eth_getBalance": 1,
    "eth_getCode": 1,
    "eth_getTransactionCount": 1,
    "eth_getStorageAt": 2,
    "eth_call": 1,
    "eth_estimateGas": 1,
    "eth_getBlockByNumber": 0,
    "eth_feeHistory": 1,
    "eth_getBlockTransactionCountByNumber": 0,
    "eth_getTransactionByBlockNumberAndIndex": 0,
}
BY_BLOCK_HASH = (
    "eth_getBlockByHash",
    "eth_getBlockTransactionCountByHash",
    "eth_getTransactionByBlockHashAndIndex",
)
BY_INDEX = ("eth_getTransactionByBlockNumberAndIndex", "eth_getTransactionByBlockHashAndIndex")

BlockByHash = Callable[[str], int]
"""Block number of a block hash; raises :class:`InvalidParams` when no such block exists."""


class InvalidParams(ValueError):
    """A request parameter the execution API does not allow (or this node does not serve)."""


def quantity(value: Any, what: str) -> int:
    """A JSON-RPC quantity (``"0x1a"``; plain JSON integers tolerated) as an int."""
    if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
        return value
    if isinstance(value, str) and _QUANTITY.fullmatch(value):
        return int(value, 16)
    raise InvalidParams(f"{what} must be a hex quantity like '0x1a', got {value!r}")


def hash32(value: Any, what: str) -> str:
    """A 32-byte hash parameter (block or transaction hash)."""
    if not isinstance(value, str) or not _HASH.fullmatch(value):
        raise InvalidParams(f"{what} must be 32 bytes of hex, got {str(value)[:80]!r}")
    return value


def block_id(value: Any, by_hash: BlockByHash) -> int | str:
    """A block parameter: tag, number, or EIP-1898 ``{"blockNumber"}`` / ``{"blockHash"}``."""
    if value is None:
        return "latest"
    if isinstance(value, str) and value in BLOCK_TAGS:
        return value
    if isinstance(value, dict):
        keys = set(value) - {"requireCanonical"}  # one chain, no forks: always canonical
        if keys == {"blockNumber"}:
            return quantity(value["blockNumber"], "blockNumber")
        if keys == {"blockHash"}:
            return by_hash(hash32(value["blockHash"], "blockHash"))
        raise InvalidParams("a block object names exactly one of 'blockNumber' or 'blockHash'")
    return quantity(value, "block")


def call_object(tx: Any, chain_id: int) -> dict[str, Any]:
    """An ``eth_call`` / ``eth_estimateGas`` transaction in eth-tester's accepted keys.

    ``input`` and ``data`` are aliases (both given and different: invalid); ``chainId`` must
    be this chain's; ``type`` is checked then inferred again from the fee fields; ``nonce``
    is dropped (calls are not checked against the sender's nonce, as in geth); a missing
    ``from`` is the zero address (never one of the node's accounts).
    """
    if not isinstance(tx, dict):
        raise InvalidParams("the transaction must be an object")
    tx = {k: v for k, v in tx.items() if v is not None}
    blobs = sorted(set(tx) & BLOB_FIELDS)
    if blobs:
        raise InvalidParams(f"blob transactions are not served (fields {', '.join(blobs)})")
    unknown = sorted(set(tx) - CALL_FIELDS)
    if unknown:
        raise InvalidParams(f"unknown transaction fields: {', '.join(unknown)}")
    if "input" in tx:
        data = _data(tx.pop("input"), "input")
        if "data" in tx and _data(tx["data"], "data") != data:
            raise InvalidParams("'input' and 'data' are both given and differ")
        tx["data"] = data
    elif "data" in tx:
        tx["data"] = _data(tx["data"], "data")
    if "chainId" in tx and quantity(tx.pop("chainId"), "chainId") != chain_id:
        raise InvalidParams(f"chainId does not match this chain ({hex(chain_id)})")
    if "type" in tx and quantity(tx.pop("type"), "type") not in SERVED_TX_TYPES:
        raise InvalidParams(f"transaction type must be one of {sorted(SERVED_TX_TYPES)}")
    tx.pop("nonce", None)
    if "gasPrice" in tx and ("maxFeePerGas" in tx or "maxPriorityFeePerGas" in tx):
        raise InvalidParams("give either gasPrice or maxFeePerGas/maxPriorityFeePerGas")
    for key in ("gas", "value", *FEE_FIELDS):
        if key in tx:
            tx[key] = quantity(tx[key], key)
    if "accessList" in tx:
        _access_list(tx["accessList"])
    if "authorizationList" in tx:
        if not isinstance(tx["authorizationList"], list) or not all(
            isinstance(a, dict) for a in tx["authorizationList"]
        ):
            raise InvalidParams("authorizationList must be a list of authorization objects")
    if "maxFeePerGas" in tx:
        tx.setdefault("maxPriorityFeePerGas", 0)  # a fee cap alone: no tip (eth-tester needs both)
    tx.setdefault("from", ZERO_ADDRESS)
    return tx


def _access_list(value: Any) -> None:
    """EIP-2930: a list of ``{"address", "storageKeys": [32-byte hex, ...]}``."""
    ok = isinstance(value, list) and all(
        isinstance(e, dict)
        and set(e) == {"address", "storageKeys"}
        and isinstance(e["address"], str)
        and _ADDRESS.fullmatch(e["address"])
        and isinstance(e["storageKeys"], list)
        and all(isinstance(k, str) and _HASH.fullmatch(k) for k in e["storageKeys"])
        for e in value
    )
    if not ok:
        raise InvalidParams(
            "accessList must be a list of {address, storageKeys: [32-byte hex]} objects"
        )


def is_unpriced(tx: dict[str, Any]) -> bool:
    """No fee field: the call runs at gas price 0 and needs no balance (geth's rule)."""
    return not any(k in tx for k in FEE_FIELDS)


def log_filter(flt: Any, by_hash: BlockByHash) -> dict[str, Any]:
    """An ``eth_getLogs`` filter; ``blockHash`` (EIP-234) becomes that block's number range."""
    if not isinstance(flt, dict):
        raise InvalidParams("the filter must be an object")
    flt = {k: v for k, v in flt.items() if v is not None}
    unknown = sorted(set(flt) - FILTER_FIELDS)
    if unknown:
        raise InvalidParams(f"unknown filter fields: {', '.join(unknown)}")
    if "blockHash" in flt:
        if "fromBlock" in flt or "toBlock" in flt:
            raise InvalidParams("blockHash excludes fromBlock/toBlock")
        number = block_id({"blockHash": flt.pop("blockHash")}, by_hash)
        flt["fromBlock"] = flt["toBlock"] = number
    if "address" in flt:
        flt["address"] = _filter_address(flt["address"])
    if "topics" in flt:
        flt["topics"] = _filter_topics(flt["topics"])
    for key in ("fromBlock", "toBlock"):
        if key in flt:
            if isinstance(flt[key], dict):
                raise InvalidParams(f"{key} is a tag or a number")
            flt[key] = _executed(_named(key, block_id, flt[key], by_hash))
    return flt


def _named(key: str, parse: Callable[..., Any], *args: Any) -> Any:
    """``parse(*args)`` with ``key`` named in its :class:`InvalidParams`."""
    try:
        return parse(*args)
    except InvalidParams as exc:
        raise InvalidParams(f"{key}: {exc}") from None


def _filter_address(value: Any) -> Any:
    """A log filter's ``address``: one address or a list of them."""
    many = value if isinstance(value, list) else [value]
    if not all(isinstance(a, str) and _ADDRESS.fullmatch(a) for a in many):
        raise InvalidParams("address must be a 20-byte hex address or a list of them")
    return value


MAX_TOPICS = 4
"""Topic positions of a log (LOG0-LOG4): a filter names at most this many."""


def _filter_topics(value: Any) -> Any:
    """A log filter's ``topics``: up to 4 positions, each null (any), a 32-byte hash, or a
    list of hashes (any of them)."""

    def topic(t: Any) -> bool:
        return isinstance(t, str) and _HASH.fullmatch(t) is not None

    ok = isinstance(value, list) and len(value) <= MAX_TOPICS and all(
        t is None or topic(t) or (isinstance(t, list) and all(topic(x) for x in t))
        for t in value
    )
    if not ok:
        raise InvalidParams(
            f"topics must be a list of at most {MAX_TOPICS} entries, each null, a 32-byte hex "
            "hash or a list of them"
        )
    return value


def _executed(block: int | str) -> int | str:
    """A log filter's block tag as a block eth-tester's filter knows: the embedded chain mines
    every transaction at once and has no forks, so no pending block holds logs and every mined
    block is final ("pending", "safe" and "finalized" are "latest"); "earliest" is block 0
    (eth-tester's filter finds nothing from that tag, and raises on "safe"/"finalized")."""
    if block in ("pending", "safe", "finalized"):
        return "latest"
    return 0 if block == "earliest" else block


def normalize(method: str, params: list[Any], chain_id: int, by_hash: BlockByHash) -> list[Any]:
    """``params`` of ``method`` rewritten for eth-tester (see the module docstring)."""
    params = list(params)
    if method in ("eth_call", "eth_estimateGas"):
        if not params:
            raise InvalidParams("missing the transaction object")
        overrides = params[2:]
        if any(o not in (None, {}) for o in overrides):
            raise InvalidParams("state and block overrides are not served")
        params = params[:2]
        params[0] = call_object(params[0], chain_id)
    elif method == "eth_getLogs":
        if len(params) != 1:
            raise InvalidParams("eth_getLogs takes one filter object")
        params[0] = log_filter(params[0], by_hash)
    elif method in BY_BLOCK_HASH and params:
        params[0] = hash32(params[0], "block hash")
    elif method in ("eth_getTransactionByHash", "eth_getTransactionReceipt") and params:
        params[0] = hash32(params[0], "transaction hash")
    if method in BY_INDEX and len(params) > 1:
        params[1] = hex(quantity(params[1], "index"))
    at = BLOCK_PARAM.get(method)
    if at is not None and at == len(params):
        params.append("latest")  # the spec's default; web3's formatters want it spelled out
    if at is not None and at < len(params):
        block = block_id(params[at], by_hash)
        # eth_call / eth_estimateGas at "pending" run on the latest state in the block that a
        # transaction sent now will be mined in (block.number one past the head), as geth's
        # pending block: what a reveal right after its commitment needs (TMC.commitCid)
        params[at] = block
    return params


def _data(value: Any, what: str) -> str:
    if not isinstance(value, str) or not _DATA.fullmatch(value):
        raise InvalidParams(f"{what} must be hex bytes ('0x...'), got {str(value)[:80]!r}")
    return value.lower()
