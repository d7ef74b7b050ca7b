"""Ethereum addresses as the platform writes them everywhere: EIP-55 checksummed."""

from __future__ import annotations

from eth_utils import is_address, to_checksum_address


def checksum(address: str) -> str:
    """EIP-55 checksummed form of ``address``; ``ValueError`` naming it if it is not one."""
    if not isinstance(address, str) or not is_address(address):
        raise ValueError(f"not an Ethereum address: {address!r}")
    return to_checksum_address(address)
