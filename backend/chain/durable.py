"""The embedded chain on disk: py-evm's key-value database kept in SQLite, committed per block.

eth-tester keeps its chain in a dict, so ``drlaas up`` lost every task, model and reputation
on a restart (issue 7). Here the same eth-tester backend runs on :class:`SQLiteKV`: the whole
store stays in memory (py-evm reads trie nodes by the thousand, so reads must not touch disk),
and every write is also recorded until :meth:`SQLiteKV.commit` writes the batch to SQLite in
one transaction. :class:`DurableBackend` commits after every mined block, before eth-tester
returns to its caller, so a transaction whose receipt anyone has seen survives SIGTERM and
kill -9 (SQLite's WAL: a committed transaction outlives the process). Nothing is pruned; the
file grows with history (a few KB per block).

The file also holds a small ``meta`` table: the platform deployment (contract addresses,
deploy block), written by the caller once the contracts are deployed, and the funded accounts'
private keys. Those are drawn at random when the file is made: eth-tester's default keys are
0x..01, 0x..02, ..., known to everyone, and the first of them deploys the contracts, so a
gateway reachable from outside would let a stranger sign as the platform admin (``/api/tx``
relays any signed transaction). The file is created readable by its owner only (0600).
A chain whose deployment was never recorded was interrupted during its first start and is
started over (nothing else can have happened on it: the gateway serves nothing before the
deployment is complete).
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from eth.db.atomic import AtomicDB
from eth.db.backends.base import BaseDB
from eth_keys import keys as eth_keys
from eth_tester import PyEVMBackend
from eth_tester.backends.pyevm.main import (
    generate_genesis_state_for_keys,
    get_default_account_keys,
    get_default_genesis_params,
    setup_tester_chain,
)

from backend.locks import hold_lock

log = logging.getLogger(__name__)

CHAIN_FILE = "chain.sqlite"
ACCOUNTS_META = "accounts"  # meta key: hex private keys of the genesis-funded accounts
_DELETED = None


class ChainNotWritten(RuntimeError):
    """A mined block could not be written to the chain file (disk full, I/O error)."""


class SQLiteKV(BaseDB):
    """A py-evm key-value database: a dict for reads, SQLite for durability (see module doc)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        # one process per chain file: a second gateway on it would fork the chain silently
        self._owner = hold_lock(self.path.with_suffix(".lock"), "embedded chain (drlaas up)")
        if not self.path.exists():  # it will hold private keys: owner-only from the start
            os.close(os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        # ``with self._db:`` is one transaction: committed on success, rolled back on error
        self._db = sqlite3.connect(self.path, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        # FULL: each block is on disk when its transaction is answered. NORMAL survived a
        # process's death but not the machine's: the chain could come back behind the index and
        # the workers' state files, which are fsynced, and it is their source of truth.
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.execute("CREATE TABLE IF NOT EXISTS kv (k BLOB PRIMARY KEY, v BLOB NOT NULL)")
        self._db.execute("CREATE TABLE IF NOT EXISTS meta (k TEXT PRIMARY KEY, v TEXT NOT NULL)")
        self._kv: dict[bytes, bytes] = dict(self._db.execute("SELECT k, v FROM kv"))
        self._dirty: dict[bytes, bytes | None] = {}

    # -- BaseDB -------------------------------------------------------------------------------
    def __getitem__(self, key: bytes) -> bytes:
        return self._kv[key]

    def __setitem__(self, key: bytes, value: bytes) -> None:
        self._kv[key] = value
        self._dirty[key] = value

    def __delitem__(self, key: bytes) -> None:
        del self._kv[key]
        self._dirty[key] = _DELETED

    def _exists(self, key: bytes) -> bool:
        return key in self._kv

    def __iter__(self) -> Iterator[bytes]:
        return iter(self._kv)

    def __len__(self) -> int:
        return len(self._kv)

    # -- durability ---------------------------------------------------------------------------
    @property
    def empty(self) -> bool:
        return not self._kv

    def commit(self) -> int:
        """Write every change since the last commit in one SQLite transaction; returns how many.
        The changes are forgotten only once written: after a failed write (disk full) they are
        written with the next commit, instead of the file missing the trie nodes of a block the
        process goes on serving (a chain with holes, found only after a restart)."""
        if not self._dirty:
            return 0
        dirty = self._dirty
        puts = [(k, v) for k, v in dirty.items() if v is not _DELETED]
        dels = [(k,) for k, v in dirty.items() if v is _DELETED]
        with self._db:
            self._db.executemany("INSERT OR REPLACE INTO kv (k, v) VALUES (?, ?)", puts)
            self._db.executemany("DELETE FROM kv WHERE k = ?", dels)
        self._dirty = {}
        return len(dirty)

    def get_meta(self, key: str) -> Any:
        row = self._db.execute("SELECT v FROM meta WHERE k = ?", (key,)).fetchone()
        return None if row is None else json.loads(row[0])

    def set_meta(self, key: str, value: Any) -> None:
        """Record ``value`` durably, together with every pending chain write."""
        self.commit()
        with self._db:
            self._db.execute(
                "INSERT OR REPLACE INTO meta (k, v) VALUES (?, ?)", (key, json.dumps(value))
            )

    def wipe(self) -> None:
        """Forget everything (an interrupted first start, see the module docstring)."""
        with self._db:
            self._db.execute("DELETE FROM kv")
            self._db.execute("DELETE FROM meta")
        self._kv.clear()
        self._dirty.clear()

    def close(self) -> None:
        self.commit()
        self._db.close()
        self._owner.close()


def _tester_chain_class(num_accounts: int) -> type:
    """eth-tester's chain class (defined inside ``setup_tester_chain``): built once in memory,
    so the durable chain has exactly the VM schedule and rules of the in-memory one."""
    _, chain = setup_tester_chain(num_accounts=num_accounts)
    return type(chain)


class DurableBackend(PyEVMBackend):
    """eth-tester's py-evm backend on a :class:`SQLiteKV` file (see the module docstring).

    A new file gets a fresh genesis with ``num_accounts`` funded accounts of random keys (see
    the module docstring); an existing one is reopened at its canonical head, with the same
    accounts."""

    def __init__(self, directory: str | Path, num_accounts: int) -> None:
        self.kv = SQLiteKV(Path(directory) / CHAIN_FILE)
        if not self.kv.empty and self.kv.get_meta("deployment") is None:
            log.warning(
                "embedded chain %s: first start was interrupted; starting over", self.kv.path
            )
            self.kv.wipe()
        self.reopened = not self.kv.empty
        chain_class = _tester_chain_class(num_accounts)
        base_db = AtomicDB(self.kv)
        if self.reopened:
            self.account_keys = self._recorded_keys(num_accounts)
            self.chain = chain_class(base_db)
        else:
            self.account_keys = tuple(
                eth_keys.PrivateKey(os.urandom(32)) for _ in range(num_accounts)
            )
            self.chain = chain_class.from_genesis(
                base_db,
                # a random extra_data: two chains made in the same second differ (identity)
                get_default_genesis_params(overrides={"extra_data": os.urandom(32)}),
                generate_genesis_state_for_keys(self.account_keys),
            )
            # genesis, then the keys; a start killed in between has no deployment either and
            # is started over (above)
            self.kv.set_meta(ACCOUNTS_META, [k.to_hex() for k in self.account_keys])

    def _recorded_keys(self, num_accounts: int) -> tuple[eth_keys.PrivateKey, ...]:
        recorded = self.kv.get_meta(ACCOUNTS_META)
        if recorded is None:  # a chain file from before the keys were random
            log.warning(
                "embedded chain %s was made with eth-tester's well-known keys: anyone can sign "
                "as its admin; keep its gateway on loopback or start a new data dir",
                self.kv.path,
            )
            return tuple(get_default_account_keys(quantity=num_accounts))
        return tuple(eth_keys.PrivateKey(bytes.fromhex(k[2:])) for k in recorded)

    def reset_to_genesis(self, *args: Any, **kwargs: Any) -> None:
        raise RuntimeError("the durable embedded chain is never reset; delete its directory")

    def mine_blocks(self, num_blocks: int = 1, coinbase: Any = None) -> tuple[bytes, ...]:
        kwargs = {} if coinbase is None else {"coinbase": coinbase}
        hashes = super().mine_blocks(num_blocks, **kwargs)
        try:
            self.kv.commit()
        except sqlite3.Error as exc:
            raise ChainNotWritten(
                f"the embedded chain mined block(s) {[h.hex() for h in hashes]} but could not "
                f"write them to {self.kv.path}: {exc}. They stay in memory and are written with "
                "the next block; if this process stops first they are lost. Free disk space."
            ) from exc
        return hashes

    def revert_to_snapshot(self, snapshot: Any) -> None:
        super().revert_to_snapshot(snapshot)
        self.kv.commit()
