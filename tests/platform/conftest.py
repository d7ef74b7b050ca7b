"""Fixtures of the platform tests: a whole embedded platform (``drlaas up`` in-process)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from backend.chain.client import Chain
from backend.store import EmbeddedStore

from .helpers import deploy, register


def worker_logs(platform: Any) -> str:
    return "\n".join(f"--- {w.log}\n{w.log.read_text()[-3000:]}" for w in platform.workers)


@pytest.fixture
def data_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    for var in (
        "DRLAAS_CHAIN",
        "DRLAAS_IPFS",
        "DRLAAS_BROKER",
        "DRLAAS_DATABASE",
        "DRLAAS_GATEWAY",
        "DRLAAS_CONTRACTS",
        "DRLAAS_MODE",
    ):
        monkeypatch.delenv(var, raising=False)
    return tmp_path / "data"


@pytest.fixture(scope="module")
def chain() -> Chain:
    """One embedded chain per test module (each test reverts what it did)."""
    return Chain.embedded(accounts=8)


@pytest.fixture
def env(chain: Chain, tmp_path: Path):
    """The platform deployed, a requester and three workers registered, a fresh store:
    (platform, actors, store); reverted after the test."""
    snap = chain.snapshot()
    p = deploy(chain)
    actors = register(p, chain.accounts[1], chain.accounts[2:5])
    store = EmbeddedStore(tmp_path / "ipfs")
    yield p, actors, store
    chain.revert(snap)
