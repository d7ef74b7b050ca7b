"""eth-tester answers -> the execution-API shapes standard clients deserialize.

What eth-tester returns through web3's formatters is close to, but not, the spec: receipts have
no ``logsBloom`` (Foundry's ``cast receipt`` and ``cast send`` refuse them) and carry
``state_root``; logs say ``"type": "mined"`` instead of ``"removed": false``; full transactions
inside blocks keep eth-tester's snake_case keys; ``y_parity`` is not ``yParity``. Its fee history
counts from the wrong block and leaves ``reward`` empty, so :func:`fee_history` computes it
from the blocks themselves, as geth does. Values stay Python values here; the JSON-RPC hex
encoding happens after (``backend.services.rpc``).
"""

from __future__ import annotations

from typing import Any

from eth_bloom import BloomFilter
from hexbytes import HexBytes

from backend.services.rpc_params import InvalidParams, quantity

MAX_FEE_HISTORY_BLOCKS = 1024
MAX_REWARD_BLOCKS = 128
"""With ``rewardPercentiles`` every receipt of every block is read (~10 ms a block under the
chain lock), so fewer blocks."""
TX_KEYS = {
    "block_hash": "blockHash",
    "block_number": "blockNumber",
    "transaction_index": "transactionIndex",
    "data": "input",
    "chain_id": "chainId",
    "access_list": "accessList",
    "authorization_list": "authorizationList",
    "gas_price": "gasPrice",
    "max_fee_per_gas": "maxFeePerGas",
    "max_priority_fee_per_gas": "maxPriorityFeePerGas",
    "max_fee_per_blob_gas": "maxFeePerBlobGas",
    "blob_versioned_hashes": "blobVersionedHashes",
    "y_parity": "yParity",
}
ACCESS_KEYS = {"storage_keys": "storageKeys"}
AUTHORIZATION_KEYS = {"chain_id": "chainId", "y_parity": "yParity"}


def shape(method: str, result: Any) -> Any:
    """``result`` of ``method`` in the execution-API shape (unchanged where it already is)."""
    if not isinstance(result, dict | list):
        return result
    if method == "eth_getTransactionReceipt" and isinstance(result, dict):
        return receipt(result)
    if method == "eth_getLogs" and isinstance(result, list):
        return [log(entry) for entry in result]
    if method in ("eth_getBlockByNumber", "eth_getBlockByHash") and isinstance(result, dict):
        txs = result.get("transactions", [])
        return {**result, "transactions": [_tx(t) if isinstance(t, dict) else t for t in txs]}
    if method.startswith("eth_getTransactionBy") and isinstance(result, dict):
        return _tx(result)
    return result


def log(entry: dict[str, Any]) -> dict[str, Any]:
    out = {k: v for k, v in entry.items() if k != "type"}
    out["removed"] = False  # one chain that never reorganises
    return out


def receipt(result: dict[str, Any]) -> dict[str, Any]:
    out = {k: v for k, v in result.items() if k != "state_root"}
    out["logs"] = [log(entry) for entry in result.get("logs", [])]
    bloom = BloomFilter()
    for entry in out["logs"]:
        bloom.add(bytes(HexBytes(entry["address"])))
        for topic in entry["topics"]:
            bloom.add(bytes(HexBytes(topic)))
    out["logsBloom"] = int(bloom)
    return out


def _tx(tx: dict[str, Any]) -> dict[str, Any]:
    out = {TX_KEYS.get(k, k): v for k, v in tx.items()}
    if isinstance(out.get("accessList"), list | tuple):
        out["accessList"] = [_keys(e, ACCESS_KEYS) for e in out["accessList"]]
    if isinstance(out.get("authorizationList"), list | tuple):
        out["authorizationList"] = [_keys(e, AUTHORIZATION_KEYS) for e in out["authorizationList"]]
    return out


def _keys(entry: Any, names: dict[str, str]) -> Any:
    return {names.get(k, k): v for k, v in entry.items()} if isinstance(entry, dict) else entry


def fee_history(tester: Any, params: list[Any]) -> dict[str, Any]:
    """``eth_feeHistory(blockCount, newestBlock, rewardPercentiles?)`` of the embedded chain.

    ``newestBlock`` is already a number or tag (``rpc_params``). Rewards are the effective
    priority fees at the given percentiles of each block's gas used, as in geth.
    """
    count = quantity(params[0], "blockCount")
    if not 1 <= count <= MAX_FEE_HISTORY_BLOCKS:
        raise InvalidParams(f"blockCount must be 1..{MAX_FEE_HISTORY_BLOCKS}")
    percentiles = params[2] if len(params) > 2 and params[2] is not None else None
    if percentiles is not None:
        ok = isinstance(percentiles, list) and len(percentiles) <= 100
        ok = ok and all(
            isinstance(p, int | float) and not isinstance(p, bool) and 0 <= p <= 100
            for p in percentiles
        )
        if not ok or any(a > b for a, b in zip(percentiles, percentiles[1:], strict=False)):
            raise InvalidParams("rewardPercentiles must be increasing numbers in 0..100")
        if count > MAX_REWARD_BLOCKS:  # rewards read every receipt of every block
            raise InvalidParams(f"blockCount must be 1..{MAX_REWARD_BLOCKS} with rewardPercentiles")
    latest = int(tester.get_block_by_number("latest")["number"])
    newest = params[1]
    if newest in ("latest", "pending", "safe", "finalized"):
        newest = latest
    elif newest == "earliest":
        newest = 0
    newest = min(int(newest), latest)
    oldest = max(0, newest - count + 1)
    blocks = [tester.get_block_by_number(n) for n in range(oldest, newest + 1)]
    following = tester.get_block_by_number(newest + 1 if newest < latest else "pending")
    out: dict[str, Any] = {
        "oldestBlock": oldest,
        "baseFeePerGas": [b.get("base_fee_per_gas", 0) for b in [*blocks, following]],
        "gasUsedRatio": [b["gas_used"] / b["gas_limit"] for b in blocks],
    }
    if percentiles is not None:
        out["reward"] = [_rewards(tester, b, percentiles) for b in blocks]
    return out


def _rewards(tester: Any, block: dict[str, Any], percentiles: list[float]) -> list[int]:
    base = block.get("base_fee_per_gas", 0)
    paid = sorted(
        (r["effective_gas_price"] - base, r["gas_used"])
        for r in (tester.get_transaction_receipt(h) for h in block["transactions"])
    )
    if not paid:
        return [0 for _ in percentiles]
    total = sum(gas for _, gas in paid)
    rewards = []
    i, used = 0, paid[0][1]
    for p in percentiles:
        while used < total * p / 100 and i < len(paid) - 1:
            i += 1
            used += paid[i][1]
        rewards.append(paid[i][0])
    return rewards
