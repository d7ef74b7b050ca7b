"""Load compiled contract artifacts and refuse stale ones.

``contracts/build.mjs`` writes ``contracts/build/<Contract>.json`` with a ``sourceHash``:
sha256 over the lines ``"<relpath>\\0<sha256(file)>\\n"`` for ``package.json``,
``solc-settings.json`` and every ``src/**/*.sol`` (sorted by relpath). This module recomputes
the same hash from the working tree, so a source edited without rebuilding is caught before
any deployment (Python never compiles; see ARCHITECTURE.md).
"""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path
from typing import Any

CONTRACTS_DIR = Path(__file__).resolve().parents[2] / "contracts"
PLATFORM_CONTRACTS = ("UsersManager", "TasksManager", "ModelsManager")


class StaleArtifactsError(RuntimeError):
    """Artifacts in contracts/build do not match the sources: run `node contracts/build.mjs`."""


def _hashed_files(root: Path) -> list[str]:
    rel = ["package.json", "solc-settings.json"]
    rel += [p.relative_to(root).as_posix() for p in (root / "src").rglob("*.sol")]
    return sorted(rel)


def source_hash(root: Path = CONTRACTS_DIR) -> str:
    """Recompute the build's source hash for the contracts tree at ``root``."""
    h = hashlib.sha256()
    for rel in _hashed_files(root):
        digest = hashlib.sha256((root / rel).read_bytes()).hexdigest()
        h.update(f"{rel}\0{digest}\n".encode())
    return h.hexdigest()


def _read(root: Path, name: str) -> dict[str, Any]:
    path = root / "build" / f"{name}.json"
    if not path.is_file():
        raise FileNotFoundError(
            f"artifact {path} is missing: run `cd contracts && npm ci && node build.mjs`"
        )
    return json.loads(path.read_text())


def check_artifacts(root: Path = CONTRACTS_DIR, names: tuple[str, ...] = PLATFORM_CONTRACTS) -> str:
    """Raise :class:`StaleArtifactsError` unless every artifact carries the current hash."""
    current = source_hash(root)
    for name in names:
        recorded = _read(root, name).get("sourceHash")
        if recorded != current:
            raise StaleArtifactsError(
                f"{root / 'build' / (name + '.json')} was built from sources with hash "
                f"{recorded}, the tree now hashes to {current}: run `node contracts/build.mjs`"
            )
    return current


@functools.cache
def load_artifact(name: str, root: Path = CONTRACTS_DIR, check: bool = True) -> dict[str, Any]:
    """The artifact dict (abi, bytecode, ...) of contract ``name``; checks staleness first."""
    if check:
        check_artifacts(root, (name,))
    return _read(root, name)


def all_abis(root: Path = CONTRACTS_DIR) -> dict[str, list[dict[str, Any]]]:
    """ABIs of every built contract (used to decode custom errors and events)."""
    out = {}
    for path in sorted((root / "build").glob("*.json")):
        out[path.stem] = json.loads(path.read_text())["abi"]
    return out
