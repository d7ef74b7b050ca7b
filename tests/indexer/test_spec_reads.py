"""The indexer's spec reads between requesters: one who posts many tasks naming CIDs nobody
holds (each read waits the find timeout) does not delay another requester's spec by all of
them. The task listing shows a task's environment only once its spec is read."""

from __future__ import annotations

import json
from pathlib import Path

from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from backend.db import models as m
from backend.indexer import Indexer
from backend.services.chain import ChainService
from backend.store import EmbeddedStore
from tests.gateway.test_indexer import any_sessions
from tests.gateway.test_indexer_durability import SPEC, MissingCidStore

__all__ = ["any_sessions"]


def test_a_requester_flooding_unreadable_specs_delays_anothers_by_one_read(
    service: ChainService, any_sessions: sessionmaker[Session], tmp_path: Path
) -> None:
    """user1 posts six tasks naming CIDs nobody provides, then user3 one task with a good spec.
    Reads go requester by requester within the same read count, so user3's spec is the second
    read, not the seventh (before: oldest task first, so it waited behind all six, one find
    timeout each, ~6 polls on a node). user1's own tasks are still read oldest first."""
    inner = EmbeddedStore(tmp_path / "ipfs")
    missing = [inner.add(f"never provided {i}".encode(), pin=False) for i in range(6)]
    store = MissingCidStore(inner, set(missing))
    good = inner.add(json.dumps(SPEC).encode())
    p, keys = service.platform, service.demo_keys
    assert keys is not None
    flooder, other = keys.address("user1"), keys.address("user3")
    with service.lock:
        p.umc.add_requester(flooder)
        p.umc.add_requester(other)
        junk = [p.tmc.add_task(flooder, domain=0, num_workers=1, reward=10**12,
                               duration=3_600, description=cid)[0] for cid in missing]
        good_id, _ = p.tmc.add_task(other, domain=0, num_workers=1, reward=10**12,
                                    duration=3_600, description=good)
    idx = Indexer(service, any_sessions, store=store, spec_budget_s=0.0,
                  spec_find_timeout_s=0.01)
    idx.poll()  # the events; a budget of 0 starts no read
    assert store.log == []
    idx.fill_specs(budget_s=30.0)
    assert store.log[:7] == [missing[0], good, *missing[1:]]  # then the flooder's, oldest first
    with any_sessions() as s:
        task = s.get(m.TaskRow, good_id)
        assert task is not None and (task.spec, task.spec_state) == (SPEC, "read")
        states = dict(s.execute(select(m.TaskRow.id, m.TaskRow.spec_state)).tuples().all())
    assert [states[t] for t in junk] == ["pending"] * 6  # one read each of SPEC_TRIES
