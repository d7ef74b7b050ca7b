"""Transaction lookups by hash in O(1) on the embedded chain, from py-evm's own index.

eth-tester finds a transaction (``eth_getTransactionByHash``, ``eth_getTransactionReceipt``,
and every receipt ``eth_getLogs`` reads) by walking the chain back from the head, block by
block: one lookup costs O(head - block), a log query over the whole chain O(head^2) — 60 s of
the chain lock for one ``eth_getLogs`` on a 500-block chain, from an anonymous ``/rpc`` client.
py-evm already keeps the canonical transaction index (hash -> block number, position) that a
real node answers from; :func:`use_indexed_lookup` makes eth-tester use it. The head block is
still searched first, as eth-tester does; a hash in neither is unknown at once (the walk would
cost O(head) for every made-up hash).
"""

from __future__ import annotations

from typing import Any

from eth.exceptions import TransactionNotFound as EvmTransactionNotFound
from eth_tester.backends.pyevm import main as pyevm_main
from eth_tester.exceptions import TransactionNotFound
from eth_utils import encode_hex


def indexed_transaction_by_hash(chain: Any, transaction_hash: bytes) -> tuple[Any, Any, int]:
    """``(block, transaction, index)`` of ``transaction_hash``, as eth-tester's lookup returns
    it, read from the canonical index; raises eth-tester's ``TransactionNotFound``."""
    head = chain.get_block()
    for index, transaction in enumerate(head.transactions):
        if transaction.hash == transaction_hash:
            return head, transaction, index
    try:
        number, index = chain.chaindb.get_transaction_index(transaction_hash)
    except EvmTransactionNotFound:
        raise TransactionNotFound(
            f"No transaction found for transaction hash: {encode_hex(transaction_hash)}"
        ) from None
    block = chain.get_canonical_block_by_number(number)
    return block, block.transactions[index], index


def use_indexed_lookup() -> None:
    """Make eth-tester's py-evm backend look transactions up by index (idempotent)."""
    pyevm_main._get_transaction_by_hash = indexed_transaction_by_hash
