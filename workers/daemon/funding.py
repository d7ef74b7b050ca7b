"""Gas money for a new key before its first transaction.

A fresh key holds nothing, and the embedded chain (eth-tester) charges the base fee, so its
first write fails. On the embedded development chain the gateway runs a faucet
(``POST /api/chain/faucet``, signed in); elsewhere the consortium funds accounts, and the error
says so instead of failing later inside a transaction.
"""

from __future__ import annotations

import re

from workers.daemon.gateway import Gateway, GatewayError
from workers.daemon.links import SetupError

#: A path on the gateway (``/rpc``): no scheme, host, ``//``, ``..``, query or backslash.
_RELATIVE_PATH = re.compile(r"/(?!/)(?:[A-Za-z0-9_\-]+/?)*")
_QUANTITY = re.compile(r"0x[0-9a-fA-F]{1,64}")


class NoGas(SetupError):
    """The key has no currency for gas and this platform's faucet cannot give any."""


def chain_balance(gw: Gateway, address: str) -> int | None:
    """Balance of ``address`` read through the gateway's ``/rpc`` (embedded chain), or ``None``
    when the gateway serves no JSON-RPC (a real node: the caller cannot check from here).
    :class:`GatewayError` naming what is wrong when an answer is not what the gateway
    answers (not an object, an ``rpc`` that is not a path on the gateway, a balance that is
    not a hex quantity)."""
    try:
        doc = gw.get("/chain/contracts")
    except GatewayError:
        return None
    if not isinstance(doc, dict):
        raise GatewayError("GET", "/chain/contracts", 200,
                           f"answer is {type(doc).__name__}, not a JSON object")
    served = doc.get("rpc")
    if not served:
        return None
    if not isinstance(served, str) or not _RELATIVE_PATH.fullmatch(served):
        raise GatewayError(
            "GET", "/chain/contracts", 200,
            f"'rpc' is {served!r}: only a path on the gateway (e.g. /rpc) is used, never "
            "another URL",
        )
    result = gw.rpc(served, "eth_getBalance", [address, "latest"])
    if not isinstance(result, str) or not _QUANTITY.fullmatch(result):
        raise GatewayError("POST", f"{served} eth_getBalance", 200,
                           f"result {str(result)[:80]!r} is not a hex quantity")
    return int(result, 16)


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
