"""What a signed raw transaction says about itself, before a node sees it: its target and the
chain it was signed for.

A node must refuse a transaction signed for another chain (EIP-155: a signature is valid on
the chain it names, so one from a public network or a test chain replays here), and one with
no chain id at all (pre-EIP-155: valid on every chain); geth refuses the latter over RPC by
default. eth-tester checks neither, so the gateway checks both for the embedded chain, on
``POST /api/tx`` and on ``/rpc``'s ``eth_sendRawTransaction``.
"""

from __future__ import annotations

from dataclasses import dataclass

import rlp  # type: ignore[import-untyped]
from eth_account.typed_transactions import TypedTransaction
from hexbytes import HexBytes
from web3 import Web3


class RawTxError(ValueError):
    """A raw transaction that cannot be decoded, or is signed for no chain or another one."""


@dataclass(frozen=True)
class RawTx:
    to: str | None
    """Checksummed target; None for a contract creation."""
    chain_id: int | None
    """The chain the signature is for; None for a pre-EIP-155 legacy transaction."""
    data: bytes = b""
    value: int = 0
    gas: int = 0


ACCEPTED_TYPES = (0x01, 0x02)
"""EIP-2718 types relayed besides legacy ones: EIP-2930 and EIP-1559. Not EIP-4844 blobs, nor
EIP-7702 set-code (0x04), whose authorization list gives accounts code other than the
transaction's own target: the embedded chain runs the Prague rules, and "only platform
contracts or plain transfers" is checked on the target alone."""


def decode_raw_tx(raw: bytes) -> RawTx:
    """Target and chain id of a signed transaction (legacy, or a type of ACCEPTED_TYPES);
    :class:`RawTxError` if it does not decode or is of another type."""
    if raw[:1] and raw[0] < 0x7F and raw[0] not in ACCEPTED_TYPES:
        raise RawTxError(
            f"transactions of type 0x{raw[0]:02x} are not accepted: sign a legacy, EIP-2930 "
            "(0x01) or EIP-1559 (0x02) transaction"
        )
    try:
        if raw[:1] and raw[0] < 0x7F:  # EIP-2718 typed: the chain id is a field
            fields = TypedTransaction.from_bytes(HexBytes(raw)).as_dict()
            to, chain_id = fields.get("to"), int(fields["chainId"])
            data, value, gas = bytes(fields.get("data", b"")), fields["value"], fields["gas"]
        else:  # legacy: [nonce, gasPrice, gas, to, value, data, v, r, s]
            items = rlp.decode(raw)
            to, v = items[3], int.from_bytes(items[6], "big")
            chain_id = (v - 35) // 2 if v >= 35 else None  # v = 27/28: no chain id
            data, value = bytes(items[5]), int.from_bytes(items[4], "big")
            gas = int.from_bytes(items[2], "big")
    except Exception:  # rlp / eth_account raise several types on malformed input
        raise RawTxError("cannot decode the transaction") from None
    target = Web3.to_checksum_address(to) if to else None
    return RawTx(target, chain_id, bytes(data), int(value), int(gas))


def check_chain(tx: RawTx, chain_id: int) -> None:
    """:class:`RawTxError` unless ``tx`` is signed for ``chain_id`` (EIP-155)."""
    if tx.chain_id is None:
        raise RawTxError(
            "only replay-protected (EIP-155) transactions are accepted: this one names no "
            f"chain id (sign it for chain {chain_id})"
        )
    if tx.chain_id != chain_id:
        raise RawTxError(
            f"the transaction is signed for chain {tx.chain_id}, this chain is {chain_id}"
        )
