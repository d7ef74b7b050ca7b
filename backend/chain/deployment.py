"""The one-shot deploy job of a consortium: wait for the chain, deploy UMC/TMC/MMC, write
``contracts.json`` (the DRLAAS_CONTRACTS file the gateway and the workers attach with).

Run again it changes nothing: when ``contracts.json`` already names contracts that have code on
this chain, the job reports them and exits, so ``docker-compose up`` can rerun it safely.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from web3 import Web3

from .client import Chain
from .consortium import read_key
from .platform import (
    ACCEPT_WINDOW,
    ALL_GPUS_BUT_NONE,
    CONTRACT_NAMES,
    REVIEW_WINDOW,
    deploy_platform,
)


def wait_for_chain(
    url: str,
    *,
    min_block: int = 1,
    timeout: float = 600.0,
    on_wait: Callable[[str], None] | None = None,
) -> int:
    """Block until the node at ``url`` answers and has produced block ``min_block`` (QBFT makes
    blocks only once a quorum of validators is connected); returns the block number.
    ``on_wait`` hears once why the chain is not ready yet, so an operator sees the job wait."""
    w3 = Web3(Web3.HTTPProvider(url, request_kwargs={"timeout": 10}))
    deadline = time.monotonic() + timeout
    last: str = "no answer"
    while True:
        try:
            block = w3.eth.block_number
            if block >= min_block:
                return block
            last = f"at block {block}"
        except Exception as exc:  # noqa: BLE001 - connection refused, DNS, timeouts, bad JSON
            last = f"{type(exc).__name__}: {exc}"
        if on_wait is not None:
            on_wait(last)
            on_wait = None
        if time.monotonic() > deadline:
            raise TimeoutError(
                f"the chain at {url} did not reach block {min_block} in {timeout:.0f} s ({last})"
            )
        time.sleep(1.0)


def existing_deployment(chain: Chain, path: Path) -> dict[str, Any] | None:
    """The deployment in ``path`` if every contract it names has code on ``chain``."""
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
        addresses = [Web3.to_checksum_address(doc[name]) for name in CONTRACT_NAMES]
    except (ValueError, KeyError, TypeError):
        return None
    if doc.get("chain_id") != chain.chain_id:
        return None
    if all(chain.w3.eth.get_code(a) for a in addresses):
        return doc
    return None


def deploy_to_file(
    url: str,
    deployer_key: str | os.PathLike[str],
    out: str | os.PathLike[str],
    *,
    min_block: int = 1,
    timeout: float = 600.0,
    accepted_gpus: int = ALL_GPUS_BUT_NONE,
    accept_window: int = ACCEPT_WINDOW,
    review_window: int = REVIEW_WINDOW,
    on_wait: Callable[[str], None] | None = None,
) -> tuple[dict[str, Any], bool]:
    """Deploy the platform from the key in ``deployer_key`` and write ``out``; returns (the
    DRLAAS_CONTRACTS document, whether this call deployed)."""
    out = Path(out)
    account = read_key(deployer_key)
    wait_for_chain(url, min_block=min_block, timeout=timeout, on_wait=on_wait)
    chain = Chain.rpc(url, private_keys=[bytes(account.key).hex()])
    found = existing_deployment(chain, out)
    if found is not None:
        return found, False
    platform = deploy_platform(
        chain,
        account.address,
        accepted_gpus=accepted_gpus,
        accept_window=accept_window,
        review_window=review_window,
    )
    doc = platform.record(platform.deployed_at)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=2) + "\n")
    os.replace(tmp, out)  # readers never see half a file
    return doc, True
