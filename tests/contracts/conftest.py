"""Fixtures for the contract tests: one embedded chain per session, a snapshot per test,
and an anvil node (JSON-RPC backend) started on a free loopback port when its binary is
installed (contracts/node_modules, `npm ci` in contracts/)."""

from __future__ import annotations

import contextlib
import dataclasses
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from backend.chain.client import Chain
from backend.chain.platform import Platform, deploy_platform, gpu_mask

CONTRACTS = Path(__file__).resolve().parents[2] / "contracts"
ANVIL_CANDIDATES = (
    CONTRACTS / "node_modules/@foundry-rs/anvil-linux-amd64/bin/anvil",
    CONTRACTS / "node_modules/@foundry-rs/anvil-linux-arm64/bin/anvil",
)
DOMAIN = 3
ACCEPTED_GPUS = {1, 2, 3}
ACCEPT_WINDOW = 600
REVIEW_WINDOW = 3_600


@dataclasses.dataclass
class Actors:
    """Named accounts: admin deploys, requester(s) post tasks, workers take them."""

    admin: str
    requester: str
    other_requester: str
    workers: list[str]
    outsider: str


def actors_of(chain: Chain) -> Actors:
    a = chain.accounts
    return Actors(a[0], a[1], a[2], a[3:-1], a[-1])


def make_platform(chain: Chain) -> Platform:
    return deploy_platform(
        chain,
        accept_window=ACCEPT_WINDOW,
        review_window=REVIEW_WINDOW,
        accepted_gpus=gpu_mask(ACCEPTED_GPUS),
        worker_approval=False,
    )


@pytest.fixture(scope="session")
def chain_session() -> Chain:
    return Chain.embedded(accounts=24)


@pytest.fixture(scope="session")
def platform_session(chain_session: Chain) -> Platform:
    return make_platform(chain_session)


@pytest.fixture
def p(chain_session: Chain, platform_session: Platform) -> Iterator[Platform]:
    """The session platform, rolled back to its deployed state after each test."""
    snap = chain_session.snapshot()
    try:
        yield platform_session
    finally:
        chain_session.revert(snap)


@pytest.fixture
def actors(chain_session: Chain) -> Actors:
    return actors_of(chain_session)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def anvil_binary() -> str | None:
    for path in ANVIL_CANDIDATES:
        if path.is_file():
            return str(path)
    return shutil.which("anvil")


@contextlib.contextmanager
def running_anvil() -> Iterator[str]:
    """A new anvil node (zero base fee, like the consortium chain) on a free port, stopped on
    exit; skips the test when the binary is missing."""
    binary = anvil_binary()
    if binary is None:
        pytest.skip("anvil binary missing: run `npm ci` in contracts/ (@foundry-rs/anvil)")
    port = _free_port()
    proc = subprocess.Popen(
        [
            binary,
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--chain-id",
            "31337",
            "--gas-limit",
            "30000000",
            "--block-base-fee-per-gas",
            "0",
            "--accounts",
            "24",
            "--silent",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 20
        while True:
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                    break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    err = proc.stderr.read().decode() if proc.stderr else ""
                    pytest.fail(f"anvil did not start on port {port}: {err}")
                time.sleep(0.05)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="session")
def anvil_url() -> Iterator[str]:
    """One anvil node for the session."""
    with running_anvil() as url:
        yield url


@pytest.fixture(params=["embedded", "anvil"])
def any_chain(request: pytest.FixtureRequest) -> Iterator[Chain]:
    """A fresh chain of each backend (the complete flows run on both)."""
    if request.param == "embedded":
        yield Chain.embedded(accounts=24)
    else:
        url = request.getfixturevalue("anvil_url")
        chain = Chain.rpc(url, n_dev_accounts=24)
        snap = chain.snapshot()
        try:
            yield chain
        finally:
            chain.revert(snap)


@pytest.fixture(scope="session")
def fast_platform(request: pytest.FixtureRequest) -> Platform:
    """A platform on anvil when its binary is installed (~4x faster per transaction than
    py-evm), else on the embedded chain; used by the transaction-heavy property tests."""
    if anvil_binary() is not None:
        chain = Chain.rpc(request.getfixturevalue("anvil_url"), n_dev_accounts=24)
    else:
        chain = request.getfixturevalue("chain_session")
    return make_platform(chain)


@pytest.fixture
def fp(fast_platform: Platform) -> Iterator[Platform]:
    """:func:`fast_platform` rolled back after each test."""
    snap = fast_platform.chain.snapshot()
    try:
        yield fast_platform
    finally:
        fast_platform.chain.revert(snap)
