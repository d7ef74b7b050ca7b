"""Fixtures of the consortium deployment tests: a generated consortium directory and anvil
started from its genesis (the one chain binary that runs here; Besu cannot)."""

from __future__ import annotations

import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from backend.chain.consortium import Layout, generate

REPO = Path(__file__).resolve().parents[2]
ANVIL = REPO / "contracts" / "node_modules" / ".bin" / "anvil"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def port_open(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False


@pytest.fixture
def consortium(tmp_path: Path) -> Layout:
    """A 4-validator consortium with 2 worker keys, generated into a temporary directory."""
    generate(tmp_path / "consortium", validators=4, workers=2, chain_id=4242)
    return Layout(tmp_path / "consortium")


def start_anvil(genesis: Path, port: int) -> subprocess.Popen[bytes]:
    """anvil initialised from ``genesis`` (its alloc and chain id) with a zero base fee, as
    the QBFT chain has (`zeroBaseFee`)."""
    if not ANVIL.exists():
        pytest.skip(f"anvil not installed ({ANVIL}; `npm ci` in contracts/)")
    return subprocess.Popen(
        [
            str(ANVIL),
            "--init",
            str(genesis),
            "--base-fee",
            "0",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--silent",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def wait_listening(proc: subprocess.Popen[bytes], port: int) -> None:
    deadline = time.monotonic() + 30
    while not port_open(port):
        if proc.poll() is not None or time.monotonic() > deadline:
            pytest.fail(f"anvil did not start on port {port} (exit {proc.poll()})")
        time.sleep(0.1)


def stop(proc: subprocess.Popen[bytes]) -> None:
    proc.terminate()
    proc.wait(timeout=10)


@pytest.fixture
def anvil(consortium: Layout) -> Iterator[str]:
    port = free_port()
    proc = start_anvil(consortium.genesis, port)
    try:
        wait_listening(proc, port)
        yield f"http://127.0.0.1:{port}"
    finally:
        stop(proc)
