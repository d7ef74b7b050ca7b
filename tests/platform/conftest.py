"""Fixtures of the platform tests: a whole embedded platform (``drlaas up`` in-process)."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest


def wait_for(
    what: str,
    fetch: Callable[[], Any],
    ok: Callable[[Any], bool],
    timeout: float,
    every: float = 0.2,
) -> Any:
    deadline = time.monotonic() + timeout
    while True:
        value = fetch()
        if ok(value):
            return value
        if time.monotonic() > deadline:
            raise AssertionError(
                f"timed out after {timeout} s waiting for {what}; last: "
                f"{json.dumps(value, default=str)[:2000]}"
            )
        time.sleep(every)


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
