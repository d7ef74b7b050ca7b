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


SERVICE_VARS = ("DRLAAS_CHAIN", "DRLAAS_IPFS", "DRLAAS_BROKER", "DRLAAS_DATABASE", "DRLAAS_GATEWAY",
                "DRLAAS_CONTRACTS", "DRLAAS_MODE")
"""Variables that would point a test's platform at services other than its own embedded ones."""


@pytest.fixture
def data_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    for var in SERVICE_VARS:
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
