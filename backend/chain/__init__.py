"""Consortium-chain client for the UMC, TMC and MMC contracts (thesis Ch. 5.3, 7.7).

One interface, two backends: :meth:`Chain.embedded` (eth-tester + py-evm, in process) and
:meth:`Chain.rpc` (any JSON-RPC node, e.g. anvil or a consortium PoA chain). Names are
imported lazily so that ``backend.chain.qos`` (pure Python) never pulls in web3.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from .artifacts import StaleArtifactsError, check_artifacts, load_artifact
    from .client import Chain, Receipt
    from .errors import ContractError
    from .gas import gas_report
    from .platform import Platform, deploy_platform

_LAZY = {
    "Chain": "client",
    "Receipt": "client",
    "ContractError": "errors",
    "StaleArtifactsError": "artifacts",
    "check_artifacts": "artifacts",
    "load_artifact": "artifacts",
    "Platform": "platform",
    "deploy_platform": "platform",
    "gas_report": "gas",
}

__all__ = [
    "Chain",
    "ContractError",
    "Platform",
    "Receipt",
    "StaleArtifactsError",
    "check_artifacts",
    "deploy_platform",
    "gas_report",
    "load_artifact",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
