"""Gas money for a new key before its first transaction.

A fresh key holds nothing, and the embedded chain (eth-tester) charges the base fee, so its
first write fails. On the embedded development chain the gateway runs a faucet
(``POST /api/chain/faucet``, signed in); elsewhere the consortium funds accounts, and the error
says so instead of failing later inside a transaction.
"""

from __future__ import annotations

from workers.daemon.gateway import Gateway, GatewayError


class NoGas(RuntimeError):
    """The key has no currency for gas and this platform's faucet cannot give any."""


def chain_balance(gw: Gateway, address: str) -> int | None:
    """Balance of ``address`` read through the gateway's ``/rpc`` (embedded chain), or ``None``
    when the gateway serves no JSON-RPC (a real node: the caller cannot check from here)."""
    try:
        served = gw.get("/chain/contracts").get("rpc")
    except GatewayError:
        return None
    if not served:
        return None
    result = gw.rpc(served, "eth_getBalance", [address, "latest"])
    return int(result, 16) if isinstance(result, str) else None


def ensure_gas(gw: Gateway) -> str:
    """Make sure the signed-in key can pay gas: ``"funded"`` (the faucet sent some),
    ``"has funds"``, or ``"unknown"`` (real chain, nothing to check here); :class:`NoGas`
    naming what to do when the key is empty and there is no faucet."""
    address = gw.address
    balance = chain_balance(gw, address)
    if balance is None:
        return "unknown"
    if balance > 0:
        return "has funds"
    try:
        gw.post("/chain/faucet", auth=True)
    except GatewayError as exc:
        raise NoGas(
            f"{address} has no currency for gas and the faucet (POST {gw.url}/api/chain/faucet, "
            f"embedded demo chain only) refused: {exc}. Wait and retry if it was rate-limited, "
            f"else ask the consortium admin to fund {address}"
        ) from exc
    return "funded"
