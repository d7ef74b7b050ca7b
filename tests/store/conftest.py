"""A real IPFS node (js-ipfs 0.66.1 from tests/ipfs-node) for the content-store tests.

The node runs offline in a temporary repo with API/Gateway/Swarm/RPC on free loopback ports and
no bootstrap peers, so tests never touch the network. ``npm ci`` runs once if node_modules is
missing. Set ``DRLAAS_TEST_IPFS_URL`` to use an already running node (e.g. Kubo) instead.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from backend.store import EmbeddedStore

NODE_DIR = Path(__file__).resolve().parents[1] / "ipfs-node"
JSIPFS = NODE_DIR / "node_modules" / ".bin" / "jsipfs"
READY_TIMEOUT_S = 60.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _ensure_node_modules() -> None:
    if JSIPFS.exists():
        return
    npm = shutil.which("npm")
    if npm is None:
        pytest.fail("npm not found: needed to install the js-ipfs test node (tests/ipfs-node)")
    result = subprocess.run(
        [npm, "ci", "--no-audit", "--no-fund"],
        cwd=NODE_DIR,
        capture_output=True,
        text=True,
        timeout=900,
    )
    if result.returncode != 0 or not JSIPFS.exists():
        pytest.fail(
            f"npm ci in {NODE_DIR} failed:\n{result.stdout[-2000:]}\n{result.stderr[-2000:]}"
        )


def _configure(repo: Path, api: int) -> None:
    config_path = repo / "config"
    config = json.loads(config_path.read_text())
    config["Addresses"].update(
        Swarm=[f"/ip4/127.0.0.1/tcp/{free_port()}"],
        API=f"/ip4/127.0.0.1/tcp/{api}",
        Gateway=f"/ip4/127.0.0.1/tcp/{free_port()}",
        RPC=f"/ip4/127.0.0.1/tcp/{free_port()}",
        Delegates=[],
    )
    config["Bootstrap"] = []
    discovery = config.setdefault("Discovery", {})
    discovery.setdefault("MDNS", {})["Enabled"] = False
    discovery.setdefault("webRTCStar", {})["Enabled"] = False
    config_path.write_text(json.dumps(config, indent=2))


def _wait_ready(proc: subprocess.Popen[bytes], url: str, log: Path) -> None:
    deadline = time.monotonic() + READY_TIMEOUT_S
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            pytest.fail(f"jsipfs daemon exited with {proc.returncode}:\n{log.read_text()[-3000:]}")
        try:
            if httpx.post(f"{url}/api/v0/version", timeout=1.0).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    pytest.fail(f"jsipfs daemon not ready after {READY_TIMEOUT_S} s:\n{log.read_text()[-3000:]}")


def _stop(proc: subprocess.Popen[bytes]) -> None:
    if proc.poll() is not None:
        return
    os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)


@pytest.fixture(scope="session")
def ipfs_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """Base URL (``http://127.0.0.1:PORT``) of a running IPFS node's RPC API."""
    external = os.environ.get("DRLAAS_TEST_IPFS_URL")
    if external:
        yield external.rstrip("/")
        return
    _ensure_node_modules()
    repo = tmp_path_factory.mktemp("ipfs-repo")
    env = dict(os.environ, IPFS_PATH=str(repo))
    init = subprocess.run(
        [str(JSIPFS), "init", "--emptyRepo"], env=env, capture_output=True, text=True, timeout=120
    )
    if init.returncode != 0:
        pytest.fail(f"jsipfs init failed:\n{init.stdout}\n{init.stderr}")
    api = free_port()
    _configure(repo, api)
    log = repo.parent / f"{repo.name}-daemon.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [str(JSIPFS), "daemon", "--offline"],
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # own process group: teardown stops node and its children
        )
    url = f"http://127.0.0.1:{api}"
    try:
        _wait_ready(proc, url, log)
        yield url
    finally:
        _stop(proc)


@pytest.fixture()
def store(tmp_path: Path) -> EmbeddedStore:
    """An embedded store of this test's own (test_embedded.py overrides it without fsync)."""
    return EmbeddedStore(tmp_path / "store")


@pytest.fixture()
def model_dir(tmp_path: Path) -> Path:
    """A model directory of 3,000 random weight bytes and a small card."""
    d = tmp_path / "model"
    d.mkdir()
    (d / "model.safetensors").write_bytes(os.urandom(3000))
    (d / "model.json").write_text(json.dumps({"format": "card", "env": {"rows": 6}}))
    return d
