"""The embedded chain on disk (backend.chain.durable): reopened with every mined transaction,
after a clean close and after kill -9 mid-stream; an interrupted first start begins again."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from backend.chain.client import Chain
from backend.chain.durable import CHAIN_FILE, ChainNotWritten, DurableBackend
from backend.locks import AlreadyHeld
from backend.services.chain import ChainService
from backend.settings import load_settings
from workers.daemon.lock import hold_daemon_lock

REPO = Path(__file__).resolve().parents[2]


def test_reopened_service_has_the_same_deployment_state_and_identity(tmp_path: Path) -> None:
    settings = load_settings(data_dir=str(tmp_path))
    first = ChainService.embedded(settings)
    p = first.platform
    requester = first.chain.accounts[3]
    p.umc.add_requester(requester)
    p.umc.add_worker(first.chain.accounts[4], [0], 2, 4, 0)
    state = (
        first.addresses(),
        p.identity,
        first.chain.w3.eth.block_number,
        first.chain.balance(requester),
    )
    first.chain.close()

    again = ChainService.embedded(settings)
    q = again.platform
    assert (again.addresses(), q.identity, again.chain.w3.eth.block_number) == state[:3]
    assert again.chain.balance(requester) == state[3]
    assert q.umc.call("isRequester", requester) is True
    assert q.umc.call("workerId", again.chain.accounts[4]) == 1
    # and it goes on: a new transaction on the reopened chain, the next block
    q.umc.add_requester(again.chain.accounts[5])
    assert again.chain.w3.eth.block_number == state[2] + 1
    again.chain.close()


def test_a_different_directory_is_a_different_chain(tmp_path: Path) -> None:
    """Even made in the same second by the same deployer (same timestamps, same addresses)."""
    a = ChainService.embedded(load_settings(data_dir=str(tmp_path / "a")))
    b = ChainService.embedded(load_settings(data_dir=str(tmp_path / "b")))
    assert a.chain.genesis_hash != b.chain.genesis_hash
    assert a.platform.identity != b.platform.identity
    a.chain.close()
    b.chain.close()


SENDER = textwrap.dedent(
    """
    import sys
    from backend.chain.client import Chain
    chain = Chain.embedded(accounts=4, directory=sys.argv[1])
    chain._tester.backend.kv.set_meta("deployment", {})  # a finished first start
    me, to = chain.accounts[0], chain.accounts[1]
    w3 = chain.w3
    for i in range(10_000):
        tx = {"to": to, "value": i + 1, "gas": 21000, "nonce": i, "chainId": chain.chain_id,
              "maxFeePerGas": 10**10, "maxPriorityFeePerGas": 0}
        h = w3.eth.send_raw_transaction(chain._keys[me].sign_transaction(tx).raw_transaction)
        w3.eth.wait_for_transaction_receipt(h)
        print(h.hex(), flush=True)
    """
)


def test_every_receipt_seen_before_kill_9_survives(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", SENDER, str(tmp_path)],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        stdout=subprocess.PIPE,
        text=True,
    )
    seen = []
    for line in proc.stdout:  # type: ignore[union-attr]
        seen.append(line.strip())
        if len(seen) == 40:
            proc.send_signal(signal.SIGKILL)
            break
    proc.wait(timeout=30)
    chain = Chain.embedded(accounts=4, directory=tmp_path)
    for h in seen:
        receipt = chain.w3.eth.get_transaction_receipt(h)
        assert receipt["status"] == 1
    # the nonce goes on from what was mined (>= what was seen: one more may have been mined)
    assert chain.w3.eth.get_transaction_count(chain.accounts[0]) >= len(seen)
    chain.close()


def genesis_of(backend: DurableBackend) -> bytes:
    return backend.chain.get_canonical_block_header_by_number(0).hash


def test_an_interrupted_first_start_begins_again(tmp_path: Path) -> None:
    backend = DurableBackend(tmp_path, num_accounts=2)  # no deployment recorded
    genesis = genesis_of(backend)
    backend.mine_blocks(3)
    backend.kv.close()
    assert (tmp_path / CHAIN_FILE).is_file()
    again = DurableBackend(tmp_path, num_accounts=2)
    assert not again.reopened and genesis_of(again) != genesis
    assert again.chain.get_canonical_head().block_number == 0


def test_one_daemon_per_worker_directory(tmp_path: Path) -> None:
    held = hold_daemon_lock(tmp_path)
    try:
        try:
            hold_daemon_lock(tmp_path)
        except AlreadyHeld as exc:
            assert str(os.getpid()) in str(exc)
        else:
            raise AssertionError("a second daemon got the lock")
    finally:
        held.close()
    hold_daemon_lock(tmp_path).close()  # released with its holder


def test_one_process_per_chain_file(tmp_path: Path) -> None:
    """A second gateway on the same data directory would fork the chain: refused by name."""
    first = Chain.embedded(accounts=2, directory=tmp_path)
    try:
        Chain.embedded(accounts=2, directory=tmp_path)
    except AlreadyHeld as exc:
        assert "embedded chain" in str(exc) and str(os.getpid()) in str(exc)
    else:
        raise AssertionError("a second process opened the same chain file")
    first.close()
    Chain.embedded(accounts=2, directory=tmp_path).close()  # free again once closed


def test_a_new_data_dir_has_its_own_random_keys_kept_across_restarts(tmp_path: Path) -> None:
    """eth-tester's default keys are 0x..01, 0x..02, ...: with them anyone could sign as the
    admin that deployed the contracts. Each data dir draws its own, owner-readable only."""
    from eth_account import Account
    from eth_tester.backends.pyevm.main import get_default_account_keys

    well_known = {Account.from_key(k.to_bytes()).address for k in get_default_account_keys(10)}
    a = ChainService.embedded(load_settings(data_dir=str(tmp_path / "a")))
    b = ChainService.embedded(load_settings(data_dir=str(tmp_path / "b")))
    accounts_a, admin_a = list(a.chain.accounts), a.platform.admin
    assert not well_known & (set(accounts_a) | set(b.chain.accounts))
    assert not set(accounts_a) & set(b.chain.accounts)
    assert admin_a == accounts_a[0] and a.chain.balance(admin_a) > 0
    assert (tmp_path / "a" / "chain" / CHAIN_FILE).stat().st_mode & 0o077 == 0
    a.chain.close()
    b.chain.close()

    again = ChainService.embedded(load_settings(data_dir=str(tmp_path / "a")))
    assert list(again.chain.accounts) == accounts_a and again.platform.admin == admin_a
    # the admin signs as before: the reopened chain holds the key, not just the address
    again.platform.umc.add_requester(again.chain.accounts[2])
    assert again.platform.umc.call("isRequester", again.chain.accounts[2]) is True
    again.chain.close()


class _DiskFullOnce:
    """The chain file's connection, whose next write fails as on a full disk."""

    def __init__(self, db: sqlite3.Connection) -> None:
        self.db, self.armed = db, True

    def executemany(self, *args: object) -> object:
        if self.armed:
            self.armed = False
            raise sqlite3.OperationalError("database or disk is full")
        return self.db.executemany(*args)

    def __getattr__(self, name: str) -> object:
        return getattr(self.db, name)

    def __enter__(self) -> object:
        return self.db.__enter__()

    def __exit__(self, *exc: object) -> object:
        return self.db.__exit__(*exc)


def test_a_failed_write_is_written_with_the_next_block(tmp_path: Path) -> None:
    """A block whose write failed (disk full) stays pending, not forgotten: the file once
    missed its trie nodes, and the reopened chain raised MissingStorageTrieNode for ever."""
    settings = load_settings(data_dir=tmp_path)
    service = ChainService.embedded(settings)
    umc, chain = service.platform.umc, service.chain
    kv = chain._tester.backend.kv
    umc.add_requester(chain.accounts[1])
    kv._db = _DiskFullOnce(kv._db)
    with pytest.raises(ChainNotWritten, match="could not write them"):
        umc.add_requester(chain.accounts[2])
    kv._db = kv._db.db  # room on the disk again
    umc.add_requester(chain.accounts[3])
    assert not kv._dirty
    head = chain.w3.eth.block_number
    chain.close()
    reopened = ChainService.embedded(settings)
    assert reopened.chain.w3.eth.block_number == head
    for i in (1, 2, 3):
        assert reopened.platform.umc.requester_status(reopened.chain.accounts[i]).name == "ACTIVE"
    reopened.platform.umc.add_requester(reopened.chain.accounts[4])
