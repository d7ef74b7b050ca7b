"""Fixtures of the platform tests: a whole embedded platform (``drlaas up`` in-process)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest


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
