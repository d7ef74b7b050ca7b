"""Indexer: resumes from the cursor after a restart without missing or duplicating events,
is idempotent on (block, log index), waits for confirmations, rebuilds on another chain."""

from __future__ import annotations

from pathlib import Path

import pytest
from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from backend.db import make_engine, make_sessionmaker, upgrade
from backend.db import models as m
from backend.indexer import Indexer
from backend.services.chain import ChainService


@pytest.fixture
def sessions(tmp_path: Path) -> sessionmaker[Session]:
    engine = make_engine(f"sqlite:///{tmp_path / 'idx.sqlite'}")
    upgrade(engine)
    return make_sessionmaker(engine)


def _chain_events(service: ChainService) -> list[tuple[int, int, str]]:
    """(block, log index, name) of every platform event, straight from the node."""
    chain = service.chain
    with service.lock:
        logs = chain.w3.eth.get_logs(
            {
                "address": [h.address for h in service.platform.contracts],
                "fromBlock": service.deploy_block,
                "toBlock": "latest",
            }
        )
        out = []
        for lg in logs:
            ev = chain._decode_logs([lg])
            out.append((lg["blockNumber"], lg["logIndex"], ev[0].name))
    return sorted(out)


def _indexed(sessions: sessionmaker[Session]) -> list[tuple[int, int, str]]:
    with sessions() as s:
        rows = s.execute(
            select(m.ChainEvent.block_number, m.ChainEvent.log_index, m.ChainEvent.name)
        ).all()
    return sorted(tuple(r) for r in rows)


def _activity(service: ChainService, first: int) -> None:
    """Requester + three workers + one allocated task, from accounts user<first>..."""
    p, keys = service.platform, service.demo_keys
    assert keys is not None
    req = keys.address(f"user{first}")
    workers = [keys.address(f"user{first + i}") for i in (1, 2, 3)]
    with service.lock:
        p.umc.add_requester(req)
        for i, w in enumerate(workers):
            p.umc.add_worker(w, [0], 2 + 4 * i, 8, 0)
        task_id, _ = p.tmc.add_task(req, domain=0, num_workers=2, reward=10**12, duration=3_600)
        p.tmc.allocate(req, task_id)


def test_restart_resumes_from_the_cursor_without_gaps_or_duplicates(
    service: ChainService, sessions: sessionmaker[Session]
) -> None:
    offers: list[tuple[int, str]] = []
    first = Indexer(service, sessions, on_offer=lambda t, w: offers.append((t, w)))
    _activity(service, 1)
    assert first.poll() > 0
    cursor = first.cursor()
    assert cursor[0] == service.block_number()
    del first  # "stop"

    _activity(service, 5)  # events produced while no indexer runs
    assert _indexed(sessions) != _chain_events(service)

    second = Indexer(service, sessions, on_offer=lambda t, w: offers.append((t, w)))
    applied = second.poll()
    assert _indexed(sessions) == _chain_events(service)
    assert applied == len(_chain_events(service)) - len(
        [e for e in _chain_events(service) if e[0] <= cursor[0]]
    )
    assert second.poll() == 0  # nothing new
    # each offer reached the hook exactly once across the restart
    with sessions() as s:
        indexed_offers = s.execute(select(m.OfferRow.task_id, m.OfferRow.worker)).all()
        assert s.scalar(select(func.count()).select_from(m.TaskRow)) == 2
    assert sorted(offers) == sorted(tuple(o) for o in indexed_offers) and len(offers) == 4

    # a lost cursor re-reads everything but applies nothing twice
    with sessions() as s:
        s.query(m.IndexCursor).delete()
        s.commit()
    assert Indexer(service, sessions).poll() == 0
    assert _indexed(sessions) == _chain_events(service)


def test_rows_match_chain_state(service: ChainService, sessions: sessionmaker[Session]) -> None:
    _activity(service, 1)
    Indexer(service, sessions).poll()
    p = service.platform
    with sessions() as s:
        for w in s.scalars(select(m.WorkerRow)):
            chain_c = p.umc.counters(w.address, 0, 0)
            assert (w.assigned, w.accepted, w.completed) == (
                chain_c["assigned"],
                chain_c["accepted"],
                chain_c["completed"],
            )
            info = p.umc.call("getWorker", w.address)
            assert (w.cpu_cores, w.ram_gb, w.gpu_series) == (info[3], info[4], info[2])
        for o in s.scalars(select(m.OfferRow)):
            assert p.tmc.offer(o.task_id, o.worker)["expiry"] == o.expiry
        t = s.get(m.TaskRow, 1)
        assert t is not None and t.offered == 2 and t.reward_wei == str(10**12)


def test_the_index_follows_offers_counted_at_the_end(
    service: ChainService, sessions: sessionmaker[Session]
) -> None:
    """An offer enters A of Eq. 17 once accepted, or at its task's end if a worker held a slot
    (docs/chain.md, "Offers that count"): nothing while the task runs, then the UMC's
    WorkerInfoUpdated events move the index and its Eq. 19 reputation with the chain."""
    from backend.chain.platform import TaskStatus
    from backend.chain.qos import reputation_fixed

    _activity(service, 1)
    p, indexer = service.platform, Indexer(service, sessions)
    indexer.poll()
    offered = [w for (t, w) in _offers(sessions) if t == 1]
    assert len(offered) == 2  # the task's two slots
    with sessions() as s:
        assert all(s.get(m.WorkerRow, w).assigned == 0 for w in offered)  # type: ignore[union-attr]
    req = service.demo_keys.address("user1")  # type: ignore[union-attr]
    worker, decliner = offered
    cid = "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yeq"
    with service.lock:
        p.tmc.transact("acceptOffer", 1, sender=worker)
        p.tmc.transact("declineOffer", 1, sender=decliner)
        p.tmc.submit_outcome(worker, 1, cid)
        p.tmc.transact("reviewOutcome", 1, worker, 5, True, sender=req)
    indexer.poll()
    with sessions() as s:
        row = s.get(m.WorkerRow, decliner)
        assert row is not None and (row.assigned, row.accepted) == (0, 0)  # task still open
    with service.lock:  # the open slot goes: only the reviewed one is left, Completed
        p.tmc.cancel_open_slots(req, 1)
    assert p.tmc.task(1)["status"] == TaskStatus.COMPLETED
    indexer.poll()
    with sessions() as s:
        for w, counts in ((worker, (1, 1, 1)), (decliner, (1, 0, 0))):
            row = s.get(m.WorkerRow, w)
            chain_c = p.umc.counters(w, 0, 0)
            assert row is not None
            assert (
                (row.assigned, row.accepted, row.completed)
                == counts
                == (
                    chain_c["assigned"],
                    chain_c["accepted"],
                    chain_c["completed"],
                )
            )
            assert row.reputation == reputation_fixed(*counts)


def test_an_outcome_paid_unreviewed_at_close_is_indexed_without_a_review(
    service: ChainService, sessions: sessionmaker[Session]
) -> None:
    """Past the review window the close pays an unreviewed outcome (OutcomePaidUnreviewed):
    the index records it accepted with no review, not as a review of 0/5, while a reviewed
    outcome of the same task keeps its review."""
    from backend.chain.platform import OfferState, TaskStatus

    _activity(service, 1)
    p, indexer = service.platform, Indexer(service, sessions)
    indexer.poll()
    req = service.demo_keys.address("user1")  # type: ignore[union-attr]
    reviewed, unreviewed = [w for (t, w) in _offers(sessions) if t == 1]
    cids = {reviewed: "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yeq",
            unreviewed: "bafkreiaqp2sovkmc3jqqi2ykiq5a3xt6ayzphuqzxzyduol4ve6ixfogje"}
    with service.lock:
        for w in (reviewed, unreviewed):
            p.tmc.transact("acceptOffer", 1, sender=w)
            p.tmc.submit_outcome(w, 1, cids[w])
        p.tmc.transact("reviewOutcome", 1, reviewed, 0, True, sender=req)  # a real 0/5
        p.chain.advance_time(3_600 + p.tmc.call("reviewWindow") + 1)
        p.tmc.transact("updateTaskStatus", 1, TaskStatus.CLOSED.value, sender=unreviewed)
    indexer.poll()
    with sessions() as s:
        got = {w: s.get(m.OutcomeRow, (1, w)) for w in (reviewed, unreviewed)}
        assert (got[reviewed].review, got[reviewed].accepted) == (0, True)  # type: ignore[union-attr]
        assert (got[unreviewed].review, got[unreviewed].accepted) == (None, True)  # type: ignore[union-attr]
        offer = s.get(m.OfferRow, (1, unreviewed))
        assert offer is not None and offer.state == OfferState.REVIEWED.name.lower()
    assert p.umc.counters(unreviewed, 0, 0)["completed"] == 1


def _offers(sessions: sessionmaker[Session]) -> list[tuple[int, str]]:
    with sessions() as s:
        return [tuple(r) for r in s.execute(select(m.OfferRow.task_id, m.OfferRow.worker))]


def test_index_lists_only_active_requesters(
    service: ChainService, sessions: sessionmaker[Session]
) -> None:
    """A pending requester is not in the index until approved; a removed one leaves it."""
    p, keys = service.platform, service.demo_keys
    assert keys is not None
    early, late = keys.address("user8"), keys.address("user9")
    with service.lock:
        p.umc.add_requester(early)  # approval off: active at once
        p.umc.set_approval_required(p.admin, True)
        p.umc.add_requester(late)  # pending
    indexer = Indexer(service, sessions)
    indexer.poll()

    def listed() -> set[str]:
        with sessions() as s:
            return {r.address for r in s.scalars(select(m.Requester))}

    assert listed() == {early}
    with service.lock:
        p.umc.approve_requester(p.admin, late)
        p.umc.remove_requester(p.admin, early)
    indexer.poll()
    assert listed() == {late}


def test_confirmations_hold_back_recent_blocks(
    service: ChainService, sessions: sessionmaker[Session]
) -> None:
    _activity(service, 1)
    head = service.block_number()
    idx = Indexer(service, sessions, confirmations=3)
    idx.poll()
    assert max(b for b, _, _ in _indexed(sessions)) <= head - 3
    assert idx.cursor()[0] == head - 3
    with service.lock:
        for _ in range(3):
            service.chain._tester.mine_blocks(1)
    idx.poll()
    assert _indexed(sessions) == _chain_events(service)


def test_failing_hook_rolls_back_and_is_retried(
    service: ChainService, sessions: sessionmaker[Session]
) -> None:
    calls: list[tuple[int, str]] = []

    def flaky(task_id: int, worker: str) -> None:
        calls.append((task_id, worker))
        if len(calls) == 1:
            raise ConnectionError("broker down")

    idx = Indexer(service, sessions, on_offer=flaky)
    _activity(service, 1)
    with pytest.raises(ConnectionError):
        idx.poll()
    assert _indexed(sessions) == []  # the whole batch rolled back, cursor not advanced
    idx.poll()
    assert _indexed(sessions) == _chain_events(service)
    assert len(calls) == 3  # first offer retried: at least once, never lost


def test_another_chain_rebuilds_the_index(
    service: ChainService, sessions: sessionmaker[Session]
) -> None:
    _activity(service, 1)
    Indexer(service, sessions).poll()
    with sessions() as s:
        s.merge(m.IndexMeta(key="anchor", value="0xother"))
        s.commit()
    idx = Indexer(service, sessions)
    assert idx.check_anchor() is True
    assert _indexed(sessions) == []
    idx.poll()
    assert _indexed(sessions) == _chain_events(service)


@pytest.fixture(params=["sqlite", "postgresql"])
def any_sessions(request: pytest.FixtureRequest, tmp_path: Path) -> sessionmaker[Session]:
    """Index sessions on SQLite and on the loopback PostgreSQL (skipped when it is not up)."""
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'idx.sqlite'}"
    else:
        from tests.backend.conftest import pg_url

        gen = pg_url.__wrapped__()  # the fixture's generator: a fresh schema, dropped after
        url = next(gen)
        request.addfinalizer(lambda: next(gen, None))
    engine = make_engine(url)
    upgrade(engine)
    request.addfinalizer(engine.dispose)
    return make_sessionmaker(engine)


def test_events_no_database_can_hold_as_written_never_stop_the_indexer(
    service: ChainService, any_sessions: sessionmaker[Session], tmp_path: Path
) -> None:
    """Anyone can addTask with any description and any document behind it: a NUL byte (which
    PostgreSQL text refuses) or a spec with NaN (which SQLite's JSON and jsonb refuse) or of
    the wrong shape is indexed as U+FFFD / no spec, and the events after it are indexed too
    (one such event stopped the indexer at its block for good)."""
    import json

    from backend.store import EmbeddedStore

    store = EmbeddedStore(tmp_path / "ipfs")
    base = {"format": "drlaas-task/1", "env": {"rows": 6, "cols": 6}, "budget": {"steps": 100}}
    nan_spec = store.add(json.dumps({**base, "experts": [{"model": "m", "qos": float("nan")}]})
                         .encode())
    bad_shape = store.add(json.dumps({**base, "experts": {"a": 1}}).encode())
    good = store.add(json.dumps(base).encode())
    p, keys = service.platform, service.demo_keys
    req = keys.address("user1")
    ids = []
    with service.lock:
        p.umc.add_requester(req)
        for description in ("evil\x00desc", nan_spec, bad_shape, good):
            task_id, _ = p.tmc.add_task(req, domain=0, num_workers=1, reward=10**12,
                                        duration=3_600, description=description)
            ids.append(task_id)
    Indexer(service, any_sessions, store=store).poll()
    assert _indexed(any_sessions) == _chain_events(service)
    with any_sessions() as s:
        rows = {t.id: t for t in s.scalars(select(m.TaskRow)).all()}
    assert rows[ids[0]].description == "evil\ufffddesc"
    assert rows[ids[1]].spec is None and rows[ids[2]].spec is None
    assert rows[ids[3]].spec == base
    states = [rows[i].spec_state for i in ids]
    assert states == ["none", "invalid", "invalid", "read"]
