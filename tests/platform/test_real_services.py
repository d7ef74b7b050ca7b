"""The issue-4 scenario again on real services on this machine: Redis as broker, PostgreSQL as
database, anvil as chain, a js-ipfs node as content store. Each missing service skips the test
with the reason."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from backend.chain.client import Chain
from drlaas.commands.scenario import run_scenario
from drlaas.commands.up import running_platform

from ..backend.conftest import port_open
from ..store.conftest import JSIPFS, free_port, ipfs_url  # noqa: F401 - the js-ipfs fixture
from .conftest import worker_logs
from .helpers import deploy

REPO = Path(__file__).resolve().parents[2]
ANVIL = REPO / "contracts" / "node_modules" / ".bin" / "anvil"
POSTGRES = "postgresql+psycopg://postgres@127.0.0.1:5432/test"
REDIS = "redis://127.0.0.1:6379/7"


@pytest.fixture
def anvil() -> Iterator[str]:
    if not ANVIL.exists():
        pytest.skip(f"anvil not installed ({ANVIL}; `npm ci` in contracts/)")
    port = free_port()
    proc = subprocess.Popen(
        [str(ANVIL), "--port", str(port), "--host", "127.0.0.1", "--silent"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 30
        while not port_open("127.0.0.1", port):
            if proc.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"anvil did not start on {url}")
            time.sleep(0.1)
        yield url
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)


@pytest.fixture
def services(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    if not port_open("127.0.0.1", 6379):
        pytest.skip("no Redis on 127.0.0.1:6379")
    if not port_open("127.0.0.1", 5432):
        pytest.skip("no PostgreSQL on 127.0.0.1:5432")
    if not JSIPFS.exists() and shutil.which("npm") is None:
        pytest.skip("js-ipfs is not installed and npm is missing")


def test_scenario_on_real_services(
    services: None,
    anvil: str,
    ipfs_url: str,  # noqa: F811
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
) -> None:
    chain = Chain.rpc(anvil)
    platform = deploy(chain)
    contracts = tmp_path / "contracts.json"
    contracts.write_text(json.dumps(platform.record(platform.deployed_at)))
    for var, value in {
        "DRLAAS_CHAIN": anvil,
        "DRLAAS_CONTRACTS": str(contracts),
        "DRLAAS_IPFS": ipfs_url,
        "DRLAAS_BROKER": REDIS,
        "DRLAAS_DATABASE": POSTGRES,
        "DRLAAS_CONFIRMATIONS": "0",
    }.items():
        monkeypatch.setenv(var, value)
    with running_platform(workers=3, data_dir=tmp_path / "data") as p:
        assert p.chain.chain.kind == "rpc" and p.settings.broker_service.kind == "redis"
        p.wait_registered()
        try:
            report = run_scenario(
                p.url,
                p.data_dir,
                steps=2000,
                timeout=300,
                say=lambda s: None,
            )
        except Exception as exc:
            raise AssertionError(f"{exc}\n{worker_logs(p)}") from exc
    events = platform.tmc.contract.events.OutcomeSubmitted().get_logs(from_block=0)
    assert [e["args"]["cid"] for e in events] == [report["cid"], report["medc"]["cid"]]
    assert report["allocated"] == [report["cid"]]
    assert report["reputation_after"] > report["reputation_before"]
