"""Deployments pinned on first use, per gateway URL, like ssh's known_hosts (docs/platform.md,
"Clients against hostile servers").

A client that learns the platform's contracts and chain id from a gateway keeps them in a pin
file, ``{gateway URL: {"chain_id": n, "contracts": {name: address}}}``, and checks later answers
against them: the CLI per key file (``<key>.platform.json``), the worker daemon per worker
directory (``platform.json``). An unreadable file is an error naming it, never pinned again
silently: a file an attacker truncated must not reopen trust on first use.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any


def read_pins(path: Path) -> dict[str, Any]:
    """The pins kept in ``path`` (``{}`` when it does not exist); ValueError naming the file
    when it cannot be read or is not a JSON object."""
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        return {}
    except (OSError, ValueError) as exc:
        raise ValueError(f"{path}: unreadable pin file ({exc}); remove it to pin again") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: not a JSON object; remove it to pin again")
    return doc


def chain_pinned_for(path: Path, gateway: str) -> int | None:
    """The chain id pinned for ``gateway`` in ``path`` (``None``: nothing pinned yet);
    ValueError naming the file when the entry's chain id is not a positive integer."""
    entry = read_pins(path).get(gateway)
    if entry is None:
        return None
    chain_id = entry.get("chain_id") if isinstance(entry, dict) else None
    if not isinstance(chain_id, int) or isinstance(chain_id, bool) or chain_id <= 0:
        raise ValueError(f"{path}: the {gateway!r} entry has no chain id; remove it to pin again")
    return chain_id


def write_pin(path: Path, gateway: str, chain_id: int, contracts: Mapping[str, str]) -> None:
    """Pin ``gateway``'s deployment in ``path``, keeping the other gateways' entries."""
    pins = read_pins(path)
    pins[gateway] = {"chain_id": chain_id, "contracts": dict(contracts)}
    _write(path, pins)


def forget_pin(path: Path, gateway: str) -> bool:
    """Remove ``gateway``'s entry from ``path`` (after a real redeployment at the same URL: the
    next use pins the new deployment); whether there was one."""
    pins = read_pins(path)
    if pins.pop(gateway, None) is None:
        return False
    _write(path, pins)
    return True


def _write(path: Path, pins: dict[str, Any]) -> None:
    """Atomically: a crash leaves the old file or the new one; concurrent writers each use
    their own temporary file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(pins, indent=1, sort_keys=True))
    os.replace(tmp, path)
