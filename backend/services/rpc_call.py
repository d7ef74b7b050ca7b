"""``eth_call`` without a gas price, run the way Ethereum nodes run it: unpaid.

A call object with no fee field (what ``cast call``, ethers and viem send by default, from the
zero address) executes at gas price 0 in geth/anvil, so the sender needs no balance.
eth-tester instead charges its default 1 gwei against the sender's balance and refuses the
call from an empty account. Here the call runs on py-evm directly, at the requested block's
header with its base fee set to 0, and every change is rolled back afterwards.

Every execution is bounded (``gas_cap``, ``bounded_estimate``): ``/rpc`` is anonymous, and an
execution holds the chain (``backend.services.rpc_budget``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from eth.exceptions import OutOfGas as EvmOutOfGas
from eth.exceptions import Revert
from eth_tester.backends.pyevm.main import EVMSpoofTransaction, _get_block_by_number
from eth_tester.exceptions import TransactionFailed
from web3.providers.eth_tester.middleware import transaction_request_transformer


class OutOfGas(Exception):
    """The execution needed more gas than its limit (geth: "gas required exceeds allowance")."""

    def __init__(self, gas: int) -> None:
        super().__init__(f"gas required exceeds allowance ({gas})")
        self.gas = gas


class ExecutionFailed(Exception):
    """The execution stopped on an error other than a revert or out of gas (invalid opcode,
    stack overflow, ...)."""


@dataclass(frozen=True)
class Execution:
    """What one unpriced execution returned and how much gas it consumed (before refunds)."""

    output: bytes
    gas_used: int


def unpriced_call(
    tester: Any, tx: dict[str, Any], block: int | str = "latest", *, gas_cap: int
) -> Execution:
    """Output of ``tx`` (execution-API keys, already checked by ``rpc_params``) at ``block``,
    with its gas limit clamped to ``gas_cap`` (a call without ``gas`` gets the cap, as geth's
    ``RPCGasCap`` does).

    A revert raises eth-tester's ``TransactionFailed`` carrying the revert data, as its own
    ``call`` does; running out of gas raises :class:`OutOfGas`, any other EVM error
    :class:`ExecutionFailed`.
    """
    gas = min(int(tx.get("gas", gas_cap)), gas_cap)
    computation = _execute(tester, tx, block, gas)
    if computation.is_error:
        _raise(computation.error, gas)
    return Execution(bytes(computation.output), gas - computation.get_gas_remaining())


def bounded_estimate(
    tester: Any,
    tx: dict[str, Any],
    block: int | str = "latest",
    *,
    gas_cap: int,
    charge: Callable[[int], None],
) -> int:
    """The smallest gas limit (to within 1/64) under which ``tx`` succeeds, found in at most
    :data:`ESTIMATE_PROBES` executions of at most ``gas_cap`` each; ``charge`` is told the gas
    of every execution.

    py-evm's own estimator bisects from the block gas limit down to a tolerance of 1 gas, up
    to ~25 full executions: a call built to succeed only near the limit would hold the chain
    for minutes. Here the first run at the cap gives the gas consumed; for the platform's
    transactions that limit already succeeds (one more run), otherwise the EIP-150 63/64
    reserve or a refund needed more and the search bisects between it and the cap.
    """
    cap = min(int(tx.get("gas", gas_cap)), gas_cap)
    first = _execute(tester, tx, block, cap)
    used = cap - first.get_gas_remaining()
    charge(used)
    if first.is_error:
        _raise(first.error, cap)

    def succeeds(gas: int) -> bool:
        computation = _execute(tester, tx, block, gas)
        charge(gas - computation.get_gas_remaining())
        return not computation.is_error

    low, high = used - 1, cap  # low fails (or is below what ran), high succeeds
    probe = used
    for _ in range(ESTIMATE_PROBES - 1):
        if high - low <= max(high // 64, 1):
            break
        if succeeds(probe):
            high = probe
        else:
            low = probe
        probe = (low + high) // 2
    return high


ESTIMATE_PROBES = 8
"""Executions one ``eth_estimateGas`` may run (the first at the cap included)."""


def _execute(tester: Any, tx: dict[str, Any], block: int | str, gas: int) -> Any:
    """Run ``tx`` with gas limit ``gas`` at gas price 0 on ``block``'s state, rolled back."""
    txn = transaction_request_transformer({**tx, "gas": gas})  # camelCase -> snake_case keys
    for fee in ("max_fee_per_gas", "max_priority_fee_per_gas", "gas_price"):
        txn.pop(fee, None)  # the execution is unpriced either way: fees change no gas used
    tester.validator.validate_inbound_transaction(txn, txn_internal_type="call")
    tester.validator.validate_inbound_block_number(block)
    raw = dict(tester.normalizer.normalize_inbound_transaction(txn))
    raw_block = tester.normalizer.normalize_inbound_block_number(block)
    backend = tester.backend
    raw["max_fee_per_gas"] = raw["max_priority_fee_per_gas"] = 0
    unsigned = backend._get_normalized_and_unsigned_evm_transaction(raw, raw_block)
    header = _get_block_by_number(backend.chain, raw_block).header
    state = backend.chain.get_vm(at_header=header.copy(base_fee_per_gas=0)).state
    snapshot = state.snapshot()
    try:
        return state.apply_transaction(EVMSpoofTransaction(unsigned, from_=raw["from"]))
    finally:
        state.revert(snapshot)


def _raise(error: BaseException, gas: int) -> None:
    if isinstance(error, Revert):
        raise TransactionFailed(error.args[0] if error.args else b"")
    if isinstance(error, EvmOutOfGas):
        raise OutOfGas(gas)
    raise ExecutionFailed(f"execution failed: {type(error).__name__}: {error}")
