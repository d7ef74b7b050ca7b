"""Indexer durability: no event stops the index (values as wide as the contracts allow, an
unstorable event kept with its error), a store that is down is not "no spec", and a chain that
went back under the cursor (embedded rollback, reorg on a node) is re-indexed."""

from __future__ import annotations

import copy
import dataclasses
import json
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from backend.db import models as m
from backend.indexer import Indexer
from backend.indexer import indexer as indexer_module
from backend.services.chain import ChainService
from backend.store import EmbeddedStore, StoreUnavailable
from backend.store.errors import FindTimeout
from tests.gateway.test_indexer import _activity, _chain_events, _indexed, any_sessions, sessions

__all__ = ["any_sessions", "sessions"]  # fixtures shared with test_indexer

SPEC = {"format": "drlaas-task/1", "env": {"rows": 6, "cols": 6}, "budget": {"steps": 100}}


def _tasks(sessions: sessionmaker[Session]) -> dict[int, m.TaskRow]:
    with sessions() as s:
        return {t.id: t for t in s.scalars(select(m.TaskRow))}


def _enrolled(service: ChainService) -> tuple[Any, str, str]:
    """The platform, with user1 registered as a requester and user2 as a worker (domain 0)."""
    p, keys = service.platform, service.demo_keys
    assert keys is not None
    req, worker = keys.address("user1"), keys.address("user2")
    with service.lock:
        p.umc.add_requester(req)
        p.umc.add_worker(worker, [0], 4, 8, 0)
    return p, req, worker


def _offer_rows(sessions: sessionmaker[Session]) -> list[tuple[int, str]]:
    with sessions() as s:
        return sorted(tuple(r) for r in s.execute(select(m.OfferRow.task_id, m.OfferRow.worker)))


def test_no_model_event_stops_the_index(
    service: ChainService,
    any_sessions: sessionmaker[Session],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A listed model with an env value of 2^32 - 1 (a valid uint32; PostgreSQL's INTEGER is
    int32) is indexed as it is, and a model whose rows the database refuses (here a summary
    value beyond any integer column) is kept in the timeline with its error, without its row:
    the task posted after them is indexed and its offer reaches the worker (either event
    stopped the indexer at its block for good)."""
    real_summary = indexer_module.summarize_env

    def summary(env: list[int]) -> Any:
        got = real_summary(env)
        return dataclasses.replace(got, walls_max=2**64) if env[3] == 5 else got

    monkeypatch.setattr(indexer_module, "summarize_env", summary)
    store = EmbeddedStore(tmp_path / "ipfs")
    p, req, worker = _enrolled(service)
    with service.lock:
        wide, _ = p.mmc.add_model(worker, store.add(b"wide"), 0, [8, 8, 2**32 - 1, 4, 0, 0])
        refused, _ = p.mmc.add_model(worker, store.add(b"refused"), 0, [8, 8, 2, 5, 0, 0])
        task_id, _ = p.tmc.add_task(req, domain=0, num_workers=1, reward=10**12, duration=3_600)
        offered, _ = p.tmc.allocate(req, task_id)
    hooked: list[tuple[int, str]] = []
    Indexer(service, any_sessions, on_offer=lambda t, w: hooked.append((t, w))).poll()

    assert _indexed(any_sessions) == _chain_events(service)
    with any_sessions() as s:
        row = s.get(m.ModelRow, wide)
        assert row is not None and row.agents == 2**32 - 1 and row.env[2] == 2**32 - 1
        assert s.get(m.ModelRow, refused) is None
        errors = {e.model_id: e.error for e in s.scalars(select(m.ChainEvent))}
    assert errors[wide] is None and errors[refused]
    assert task_id in _tasks(any_sessions)
    assert hooked == _offer_rows(any_sessions) == [(task_id, offered[0])]


class FlakyStore:
    """``inner``, unreachable for the first ``down`` reads (an IPFS node restarting)."""

    def __init__(self, inner: EmbeddedStore, down: int) -> None:
        self.inner, self.down = inner, down

    def with_find_timeout(self, seconds: float) -> FlakyStore:
        return self

    def get(self, *args: Any, **kwargs: Any) -> bytes:
        if self.down > 0:
            self.down -= 1
            raise StoreUnavailable("http://ipfs:5001", "connection refused (node restarting)")
        return self.inner.get(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def test_a_store_that_is_down_is_not_taken_for_no_spec(
    service: ChainService, sessions: sessionmaker[Session], tmp_path: Path
) -> None:
    """A task's spec read while the store is unreachable: the task's event is indexed all the
    same and its spec stays pending, so the task gets its spec once the store is back (it was
    indexed with none, for good)."""
    inner = EmbeddedStore(tmp_path / "ipfs")
    cid = inner.add(json.dumps(SPEC).encode())
    p, keys = service.platform, service.demo_keys
    assert keys is not None
    req = keys.address("user1")
    with service.lock:
        p.umc.add_requester(req)
        task_id, _ = p.tmc.add_task(
            req, domain=0, num_workers=1, reward=10**12, duration=3_600, description=cid
        )
    idx = Indexer(service, sessions, store=FlakyStore(inner, down=1))  # type: ignore[arg-type]
    idx.poll()
    assert _indexed(sessions) == _chain_events(service)  # the events do not wait for the store
    task = _tasks(sessions)[task_id]
    assert (task.spec, task.spec_state, task.spec_tries) == (None, "pending", 0)
    idx.poll()
    task = _tasks(sessions)[task_id]
    assert (task.spec, task.spec_state) == (SPEC, "read")


class MissingCidStore:
    """``inner``, except for the CIDs in ``missing``, which nobody provides: as on an IPFS node,
    a read of one looks for it until the find timeout, then fails (``FindTimeout``)."""

    def __init__(self, inner: EmbeddedStore, missing: set[str], find_timeout: float = 10.0):
        self.inner, self.missing, self.find_timeout = inner, missing, find_timeout
        self.reads: Counter[str] = Counter()  # shared with the copies below
        self.log: list[str] = []

    def with_find_timeout(self, seconds: float) -> MissingCidStore:
        quick = copy.copy(self)
        quick.find_timeout = min(self.find_timeout, seconds)
        return quick

    def get(self, cid: str, **kwargs: Any) -> bytes:
        self.reads[str(cid)] += 1
        self.log.append(str(cid))
        if str(cid) in self.missing:
            time.sleep(self.find_timeout)
            raise FindTimeout(str(cid), after=self.find_timeout)
        return self.inner.get(cid, **kwargs)


def test_specs_nobody_holds_never_hold_up_the_events(
    service: ChainService, sessions: sessionmaker[Session], tmp_path: Path
) -> None:
    """Tasks whose descriptions name CIDs the node cannot find (anyone can addTask with any
    text): every event of the poll is indexed and the next task's offer reaches its worker at
    once; a poll starts spec reads only within its budget (here at most 3 reads of 0.05 s in
    0.12 s, whatever the number of such tasks); a good spec is not queued behind the missing
    ones' retries; each missing CID is read ``SPEC_TRIES`` times, then marked missing and not
    read again before its retry time. (Before, each one waited the node's 10 s find timeout
    inside the batch of events.)"""
    inner = EmbeddedStore(tmp_path / "ipfs")
    missing = {inner.add(f"never provided {i}".encode(), pin=False) for i in range(4)}
    store = MissingCidStore(inner, missing)
    assert Indexer(service, sessions, store=store)._spec_store.find_timeout == (  # type: ignore[union-attr]
        indexer_module.SPEC_FIND_TIMEOUT_S
    ) < store.find_timeout
    good = inner.add(json.dumps(SPEC).encode())
    p, req, _ = _enrolled(service)
    with service.lock:
        junk = [
            p.tmc.add_task(req, domain=0, num_workers=1, reward=10**12, duration=3_600,
                           description=cid)[0]
            for cid in sorted(missing)
        ]
        good_id, _ = p.tmc.add_task(
            req, domain=0, num_workers=1, reward=10**12, duration=3_600, description=good
        )
        offered, _ = p.tmc.allocate(req, good_id)
    hooked: list[tuple[int, str]] = []
    idx = Indexer(service, sessions, store=store, on_offer=lambda t, w: hooked.append((t, w)),
                  spec_budget_s=0.12, spec_find_timeout_s=0.05)
    idx.poll()
    assert _indexed(sessions) == _chain_events(service)
    assert hooked == [(good_id, offered[0])]
    assert 1 <= sum(store.reads.values()) <= 3
    for _ in range(100):  # at least one read per poll: 13 reads in all
        if {t.spec_state for t in _tasks(sessions).values()} <= {"read", "missing"}:
            break
        idx.poll()
    first_retry = next(i for i, c in enumerate(store.log) if c in store.log[:i])
    assert store.log.index(good) < first_retry  # not queued behind the missing CIDs' retries
    tasks = _tasks(sessions)
    assert (tasks[good_id].spec, tasks[good_id].spec_state) == (SPEC, "read")
    assert {tasks[t].spec_state for t in junk} == {"missing"}
    assert {store.reads[c] for c in missing} == {indexer_module.SPEC_TRIES}
    reads = sum(store.reads.values())
    idx.poll()
    assert sum(store.reads.values()) == reads  # not before its retry time


def test_a_missing_spec_is_asked_for_again_later_backing_off(
    service: ChainService, sessions: sessionmaker[Session], tmp_path: Path
) -> None:
    """A spec the store did not find in ``SPEC_TRIES`` reads (the requester's node was
    offline) is read again ``SPEC_RETRY_S`` after, then twice as long after each miss up to
    ``SPEC_RETRY_MAX_S``, and indexed as read once the store has it: the task gets its
    environment in the listing instead of staying ``missing`` for good."""
    inner = EmbeddedStore(tmp_path / "ipfs")
    late = inner.add(json.dumps(SPEC).encode())
    store = MissingCidStore(inner, {late})
    p, req, _ = _enrolled(service)
    with service.lock:
        task_id, _ = p.tmc.add_task(req, domain=0, num_workers=1, reward=10**12,
                                    duration=3_600, description=late)
    now = [1_000_000.0]
    idx = Indexer(service, sessions, store=store, spec_find_timeout_s=0.01,
                  clock=lambda: now[0])
    for _ in range(indexer_module.SPEC_TRIES):
        idx.poll()
    task = _tasks(sessions)[task_id]
    assert (task.spec_state, task.spec_retry_at) == ("missing", 1_000_000 + 60)
    waits = []
    for _ in range(8):  # due reads that still find nothing: 60 s, 120 s, ... 3600 s at most
        retry_at = _tasks(sessions)[task_id].spec_retry_at
        now[0] = retry_at - 1
        reads = store.reads[late]
        idx.poll()
        assert store.reads[late] == reads  # not due yet
        now[0] = retry_at
        idx.poll()
        assert store.reads[late] == reads + 1
        waits.append(_tasks(sessions)[task_id].spec_retry_at - retry_at)
    assert waits == [120, 240, 480, 960, 1920, 3600, 3600, 3600]
    assert indexer_module.SPEC_RETRY_S == 60 and indexer_module.SPEC_RETRY_MAX_S == 3600
    store.missing.clear()  # the requester's node is back
    now[0] = _tasks(sessions)[task_id].spec_retry_at
    idx.poll()
    task = _tasks(sessions)[task_id]
    assert (task.spec, task.spec_state, task.spec_retry_at) == (SPEC, "read", None)


def _tx_hashes(sessions: sessionmaker[Session]) -> set[str]:
    with sessions() as s:
        return set(s.scalars(select(m.ChainEvent.tx_hash)))


def _chain_tx_hashes(service: ChainService) -> set[str]:
    with service.lock:
        logs = service.chain.w3.eth.get_logs(
            {
                "address": [h.address for h in service.platform.contracts],
                "fromBlock": service.deploy_block,
                "toBlock": "latest",
            }
        )
    return {"0x" + bytes(lg["transactionHash"]).hex() for lg in logs}


def test_a_chain_that_went_back_is_reindexed(
    service: ChainService, sessions: sessionmaker[Session]
) -> None:
    """The embedded chain loses its last blocks (its file is not fsynced per block, the index
    is): the index drops what the chain no longer has, and indexes the task later mined at
    those heights, whose offer reaches its worker; offers of the blocks that stayed are not
    handed over again."""
    p, keys = service.platform, service.demo_keys
    assert keys is not None
    hooked: list[tuple[int, str]] = []
    idx = Indexer(service, sessions, on_offer=lambda t, w: hooked.append((t, w)))
    _activity(service, 1)  # task 1, two offers
    idx.poll()
    kept_offers = _offer_rows(sessions)
    req = keys.address("user1")
    power_cut = service.chain.snapshot()
    with service.lock:
        lost, _ = p.tmc.add_task(
            req, domain=0, num_workers=2, reward=10**12, duration=3_600, description="LOST"
        )
        p.tmc.allocate(req, lost)
    idx.poll()
    assert _tasks(sessions)[lost].description == "LOST" and len(hooked) == 4
    cursor_before = idx.cursor()[0]

    service.chain.revert(power_cut)  # the chain is now behind the index
    assert service.block_number() < cursor_before
    idx.poll()
    assert lost not in _tasks(sessions) and _offer_rows(sessions) == kept_offers
    assert _indexed(sessions) == _chain_events(service)

    with service.lock:
        again, _ = p.tmc.add_task(
            req, domain=0, num_workers=1, reward=9 * 10**12, duration=3_600, description="AFTER"
        )
        offered, _ = p.tmc.allocate(req, again)
    assert again == lost and service.block_number() == cursor_before  # the same heights
    idx.poll()
    task = _tasks(sessions)[again]
    assert (task.description, task.num_workers, task.reward_wei) == ("AFTER", 1, str(9 * 10**12))
    assert _offer_rows(sessions) == sorted([*kept_offers, (again, offered[0])])
    assert _indexed(sessions) == _chain_events(service)
    assert _tx_hashes(sessions) == _chain_tx_hashes(service)  # no event of the lost blocks
    assert hooked[4:] == [(again, offered[0])]  # task 1's offers were not handed over again


@pytest.fixture
def anvil() -> Iterator[str]:
    """A fresh anvil node (anvil_reorg rewrites its history, so never the session's)."""
    from tests.contracts.conftest import running_anvil

    with running_anvil() as url:
        yield url


def test_a_reorg_deeper_than_the_confirmations_is_reindexed(
    anvil: str, sessions: sessionmaker[Session]
) -> None:
    """A node replaces blocks the indexer had confirmed (anvil_reorg deeper than
    ``confirmations``): the orphaned task and offers leave the index, the new fork's task is
    indexed and its offer handed over."""
    from backend.chain.client import Chain
    from backend.chain.platform import deploy_platform
    from backend.services.chain import ALL_GPU_SERIES

    chain = Chain.rpc(anvil, n_dev_accounts=24)
    p = deploy_platform(chain, accepted_gpus=ALL_GPU_SERIES, worker_approval=False)
    service = ChainService(chain, p, p.deployed_at)
    req, workers = chain.accounts[1], chain.accounts[2:5]
    p.umc.add_requester(req)
    for i, w in enumerate(workers):
        p.umc.add_worker(w, [0], 2 + 4 * i, 8, 0)
    hooked: list[tuple[int, str]] = []
    idx = Indexer(service, sessions, confirmations=2, on_offer=lambda t, w: hooked.append((t, w)))
    fork = chain.w3.eth.block_number
    orphan, _ = p.tmc.add_task(
        req, domain=0, num_workers=2, reward=10**12, duration=7_200, description="ORPHANED"
    )
    p.tmc.allocate(req, orphan)
    for _ in range(3):
        chain.w3.provider.make_request("evm_mine", [])  # type: ignore[arg-type]
    idx.poll()
    assert _tasks(sessions)[orphan].description == "ORPHANED" and len(hooked) == 2

    depth = chain.w3.eth.block_number - fork
    assert "error" not in chain.w3.provider.make_request("anvil_reorg", [depth, []])  # type: ignore[arg-type]
    task_id, _ = p.tmc.add_task(
        req, domain=0, num_workers=1, reward=5 * 10**12, duration=7_200, description="NEW FORK"
    )
    offered, _ = p.tmc.allocate(req, task_id)
    for _ in range(3):
        chain.w3.provider.make_request("evm_mine", [])  # type: ignore[arg-type]
    idx.poll()
    task = _tasks(sessions)[task_id]
    assert (task.description, task.num_workers) == ("NEW FORK", 1)
    assert _offer_rows(sessions) == [(task_id, offered[0])]
    assert _tx_hashes(sessions) == _chain_tx_hashes(service)
    assert hooked[2:] == [(task_id, offered[0])]
