"""``eth_call`` without a gas price, run the way Ethereum nodes run it: unpaid.

A call object with no fee field (what ``cast call``, ethers and viem send by default, from the
zero address) executes at gas price 0 in geth/anvil, so the sender needs no balance.
eth-tester instead charges its default 1 gwei against the sender's balance and refuses the
call from an empty account. Here the call runs on py-evm directly, at the requested block's
header with its base fee set to 0, and every change is rolled back afterwards.
"""

from __future__ import annotations

from typing import Any

from eth.exceptions import Revert
from eth_tester.backends.pyevm.main import EVMSpoofTransaction, _get_block_by_number
from eth_tester.exceptions import TransactionFailed
from web3.providers.eth_tester.middleware import transaction_request_transformer


def unpriced_call(tester: Any, tx: dict[str, Any], block: int | str = "latest") -> bytes:
    """Output of ``tx`` (execution-API keys, already checked by ``rpc_params``) at ``block``.

    A revert raises eth-tester's ``TransactionFailed`` carrying the revert data, as its own
    ``call`` does.
    """
    txn = transaction_request_transformer(tx)  # camelCase -> eth-tester's snake_case keys
    tester.validator.validate_inbound_transaction(txn, txn_internal_type="call")
    tester.validator.validate_inbound_block_number(block)
    raw = dict(tester.normalizer.normalize_inbound_transaction(txn))
    raw_block = tester.normalizer.normalize_inbound_block_number(block)
    backend = tester.backend
    raw.setdefault("gas", backend._max_available_gas())
    raw["max_fee_per_gas"] = raw["max_priority_fee_per_gas"] = 0
    unsigned = backend._get_normalized_and_unsigned_evm_transaction(raw, raw_block)
    header = _get_block_by_number(backend.chain, raw_block).header
    state = backend.chain.get_vm(at_header=header.copy(base_fee_per_gas=0)).state
    snapshot = state.snapshot()
    try:
        computation = state.apply_transaction(EVMSpoofTransaction(unsigned, from_=raw["from"]))
    finally:
        state.revert(snapshot)
    if computation.is_error:
        error = computation.error
        if isinstance(error, Revert):
            raise TransactionFailed(error.args[0] if error.args else b"")
        raise TransactionFailed(str(error))
    return bytes(computation.output)
