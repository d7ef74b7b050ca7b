"""The chain offer watcher of the worker daemon (``workers.daemon.offer_watch``): an offer whose
broker message never arrives (consumed by another worker on a shared broker, purged, lost with
a broker restarted without persistence) is found on chain and enqueued, again a few times if no
job comes of it (a thief on the broker); offers the chain
no longer holds for this worker, or that the daemon has in hand, are not; the cursor survives
a restart; a failing or garbling node never stops it."""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import requests

from backend.chain.platform import OfferState
from workers.daemon import offer_watch
from workers.daemon.handler import OfferHandler
from workers.daemon.offer_watch import OfferWatcher, poll_interval_from_env

from .helpers import post_task

IDLE = (frozenset(), 1e9)  # no handle_offer running, for long


def handler_for(p, address: str, store, tmp_path: Path) -> OfferHandler:
    return OfferHandler(account=p.chain._keys[address], platform=p, store=store,
                        data_dir=tmp_path / "w" / address)


class Recorder:
    """An ``on_offer`` that records instead of sending to a broker."""

    def __init__(self) -> None:
        self.calls: list[tuple[int, str]] = []

    def __call__(self, task_id: int, worker: str) -> None:
        self.calls.append((task_id, worker))


def watcher_for(h: OfferHandler, enqueue: Any, **kw: Any) -> OfferWatcher:
    kw.setdefault("grace_s", 0.0)
    kw.setdefault("handling", lambda: IDLE)
    return OfferWatcher(h, enqueue, **kw)


def test_an_offer_no_message_delivered_is_found_and_enqueued_once(env, tmp_path: Path) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)  # no on_offer: no message
    worker = offered[0]
    rec = Recorder()
    h = handler_for(p, worker, store, tmp_path)
    clock = [1000.0]
    w = watcher_for(h, rec, grace_s=60.0, clock=lambda: clock[0])
    assert w.tick() == []  # seen: the broker may still deliver it within the grace
    clock[0] += 61
    assert w.tick() == [task_id]
    assert rec.calls == [(task_id, worker)]  # the queue and key of the indexer's on_offer
    assert w.found == 1
    assert w.tick() == [] and rec.calls == [(task_id, worker)]  # not again within the grace
    assert w.block == p.chain.w3.eth.block_number
    h._save(task_id, phase="declined")  # the message reached the daemon, which answered it
    clock[0] += 61
    assert w.tick() == [] and w.pending == {}  # in hand: never again


def test_an_offer_whose_message_is_taken_again_is_enqueued_a_few_times(
    env, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A consumer on the broker that takes every message of our queue: the watcher enqueues the
    offer again each grace while no job appears, MAX_ENQUEUES times, then says what happens."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    rec = Recorder()  # a thief: nothing it is given reaches the daemon
    clock = [1000.0]
    w = watcher_for(handler_for(p, offered[0], store, tmp_path), rec, grace_s=60.0,
                    clock=lambda: clock[0])
    assert w.tick() == []
    for _ in range(offer_watch.MAX_ENQUEUES + 2):
        clock[0] += 61
        w.tick()
    assert rec.calls == [(task_id, offered[0])] * offer_watch.MAX_ENQUEUES
    assert w.pending == {}
    assert "another consumer on the broker" in caplog.text
    # a restarted watcher remembers the tries
    w2 = watcher_for(handler_for(p, offered[0], store, tmp_path), rec, clock=lambda: clock[0])
    assert w2.tick() == []
    assert len(rec.calls) == offer_watch.MAX_ENQUEUES


def test_offers_not_ours_or_answered_or_in_hand_are_not_enqueued(env, tmp_path: Path) -> None:
    p, actors, store = env
    # another worker's offer: a watcher of a worker that was offered nothing sees nothing
    t_other, offered, _ = post_task(p, store, actors.requester)
    idle = next(a for a in actors.workers if a not in offered)
    rec_idle = Recorder()
    assert watcher_for(handler_for(p, idle, store, tmp_path), rec_idle).tick() == []
    assert rec_idle.calls == []

    me = actors.workers[0]
    h = handler_for(p, me, store, tmp_path)
    t_expired, off, _ = post_task(p, store, actors.requester, num_workers=3)
    assert me in off
    p.chain.advance_time(700)  # past the 600 s acceptance window
    t_accepted, off, _ = post_task(p, store, actors.requester, num_workers=3)
    assert me in off
    p.tmc.transact("acceptOffer", t_accepted, sender=me)
    t_in_hand, off, _ = post_task(p, store, actors.requester, num_workers=3)
    assert me in off
    h._save(t_in_hand, phase="accepting")  # being accepted by the daemon
    t_live, off, _ = post_task(p, store, actors.requester, num_workers=3)
    assert me in off
    assert p.tmc.offer(t_expired, me)["state"] == OfferState.OFFERED  # expired, not marked yet
    assert p.tmc.offer(t_in_hand, me)["state"] == OfferState.OFFERED

    rec = Recorder()
    w = watcher_for(h, rec)
    assert w.tick() == [t_live]
    assert rec.calls == [(t_live, me)]
    assert set(w.pending) == {t_live}  # the others are not followed any more


def test_an_offer_being_handled_waits_and_a_stuck_check_is_enqueued(
    env, tmp_path: Path
) -> None:
    """A job in phase ``offered`` is enqueued only when no handle_offer runs for it, and no
    offer is enqueued while the daemon handles another (its message may wait in the queue)."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered[0], store, tmp_path)
    h._save(task_id, phase="offered")  # a check that ended outside the Celery retries
    rec = Recorder()
    now: list[Any] = [(frozenset({task_id}), 0.0)]
    w = watcher_for(h, rec, handling=lambda: now[0])
    assert w.tick() == []  # being handled
    now[0] = (frozenset({task_id + 1}), 0.0)
    assert w.tick() == []  # the daemon is busy with another job
    now[0] = (frozenset(), 5.0)
    w.grace_s = 10.0
    assert w.tick() == []  # idle for less than the grace
    now[0] = IDLE
    w.grace_s = 0.0
    assert w.tick() == [task_id] and rec.calls == [(task_id, offered[0])]


def test_the_cursor_and_followed_offers_survive_a_restart(env, tmp_path: Path) -> None:
    p, actors, store = env
    t1, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)
    clock = [1000.0]
    rec = Recorder()
    w1 = watcher_for(h, rec, grace_s=60.0, clock=lambda: clock[0])
    assert w1.tick() == []  # seen, not due yet: the broker may still deliver it
    cursor = w1.block
    assert cursor == p.chain.w3.eth.block_number and w1.pending == {t1: 1000.0}

    clock[0] += 61
    w2 = watcher_for(h, rec, grace_s=60.0, clock=lambda: clock[0])  # the daemon restarted
    ranges: list[tuple[int, int]] = []
    scan = w2._offers_in
    w2._offers_in = lambda lo, hi: (ranges.append((lo, hi)), scan(lo, hi))[1]  # type: ignore[method-assign]
    assert w2.tick() == [t1]  # followed across the restart, though its block is behind
    assert ranges[0][0] >= cursor + 1 - offer_watch.REORG_OVERLAP  # no rescan of the window

    w3 = watcher_for(h, rec, grace_s=60.0, clock=lambda: clock[0])
    assert w3.tick() == []  # enqueued before the restart: not again within the grace
    assert rec.calls == [(t1, worker)]
    assert w3.block == w2.block


def test_a_failing_node_does_not_stop_the_watcher(
    env, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered[0], store, tmp_path)
    rec = Recorder()
    w = watcher_for(h, rec, poll_s=0.01)
    monkeypatch.setattr(offer_watch, "MAX_BACKOFF_S", 0.05)
    down = threading.Event()
    down.set()
    real = p.tmc.offer

    def offer(*args: Any) -> Any:
        if down.is_set():
            raise requests.ConnectionError("connection refused")
        return real(*args)

    monkeypatch.setattr(p.tmc, "offer", offer)
    stop = threading.Event()
    thread = threading.Thread(target=w.run, args=(stop,), daemon=True)
    with caplog.at_level(logging.WARNING, logger="workers.daemon.offer_watch"):
        thread.start()
        deadline = time.monotonic() + 10
        while w.errors < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert w.errors >= 3 and thread.is_alive() and rec.calls == []
        down.clear()  # the node is back
        while not rec.calls and time.monotonic() < deadline:
            time.sleep(0.01)
        stop.set()
        thread.join(5)
    assert rec.calls == [(task_id, offered[0])]
    assert "chain node unreachable" in caplog.text


def test_garbage_from_the_node_is_skipped(
    env, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    p, actors, store = env
    t1, offered, _ = post_task(p, store, actors.requester, num_workers=3)
    me = actors.workers[0]
    assert me in offered
    t2, offered, _ = post_task(p, store, actors.requester, num_workers=3)
    assert me in offered
    eth = p.chain.w3.eth
    real_logs, real_offer = eth.get_logs, p.tmc.offer
    monkeypatch.setattr(eth, "get_logs", lambda q: [5, {"topics": "junk"}, *real_logs(q)])
    monkeypatch.setattr(p.tmc, "offer", lambda tid, w: (
        {"state": "offered", "expiry": None} if tid == t1 else real_offer(tid, w)))
    rec = Recorder()
    w = watcher_for(handler_for(p, me, store, tmp_path), rec)
    with caplog.at_level(logging.WARNING, logger="workers.daemon.offer_watch"):
        assert w.tick() == [t2]
    assert "log entry" in caplog.text and f"offer of task {t1} skipped" in caplog.text
    monkeypatch.setattr(p.tmc, "offer", real_offer)
    # a sane answer later: enqueued then (t2 again: no job came of it, the grace here is 0)
    assert w.tick() == [t1, t2]


def test_the_poll_interval_setting_is_checked() -> None:
    assert poll_interval_from_env({}) == offer_watch.DEFAULT_POLL_S
    assert poll_interval_from_env({"DRLAAS_WORKER_OFFER_POLL_S": "0"}) == 0
    assert poll_interval_from_env({"DRLAAS_WORKER_OFFER_POLL_S": " 2.5 "}) == 2.5
    for bad in ("-1", "soon", "nan", "inf"):
        with pytest.raises(ValueError, match="DRLAAS_WORKER_OFFER_POLL_S"):
            poll_interval_from_env({"DRLAAS_WORKER_OFFER_POLL_S": bad})
    assert offer_watch.start_watcher(object(), Recorder(), poll_s=0) is None


@pytest.mark.parametrize("broker", ["embedded", "redis://127.0.0.1:6379/9"])
def test_a_stolen_message_is_enqueued_again_on_a_real_broker(
    env, tmp_path: Path, broker: str
) -> None:
    """The indexer's message is consumed by another member of the crowd (it holds the broker's
    credentials); the watcher puts the job back on the worker's queue under the same key."""
    from backend.celery_app import make_celery, worker_queue
    from backend.settings import load_settings
    from workers.daemon import tasks

    if broker.startswith("redis://"):
        import socket

        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", 6379)) != 0:
                pytest.skip("no Redis listening on 127.0.0.1:6379")
    settings = load_settings(data_dir=tmp_path / "gateway", broker=broker)
    app = make_celery(settings)
    on_offer = tasks.make_on_offer(settings, app)
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    queue = worker_queue(worker)

    def take_all() -> list[tuple[str, list[Any]]]:
        got = []
        with app.connection_for_read() as conn, conn.SimpleQueue(queue) as q:
            while True:
                try:
                    msg = q.get(timeout=1)
                except q.Empty:
                    return got
                got.append((msg.headers["id"], msg.decode()[0]))
                msg.ack()

    try:
        on_offer(task_id, worker)  # the indexer's message ...
        assert take_all() == [(tasks.offer_key(task_id, worker), [task_id, worker])]  # stolen
        w = watcher_for(handler_for(p, worker, store, tmp_path), on_offer)
        assert w.tick() == [task_id]
        assert take_all() == [(tasks.offer_key(task_id, worker), [task_id, worker])]
    finally:
        with app.connection_for_write() as conn:  # leave no queue behind on a shared server
            try:
                conn.default_channel.queue_delete(queue)
            except Exception:  # noqa: BLE001 - cleanup best effort
                pass


def test_the_daemon_knows_which_offer_it_is_handling(tmp_path: Path) -> None:
    """Celery's task_prerun / task_postrun tell the watcher what handle_offer runs now."""
    from backend.celery_app import make_celery
    from backend.settings import Settings
    from workers.daemon import tasks

    seen: list[Any] = []

    class Runtime:
        def handle(self, task_id: int, worker: str) -> dict[str, Any]:
            seen.append(offer_watch.handling())
            return {"task_id": task_id, "status": "declined"}

    make_celery(Settings(data_dir=tmp_path / "celery")).set_current()
    tasks.set_runtime(Runtime())  # type: ignore[arg-type]
    try:
        tasks.handle_offer.apply(args=[41, "0x" + "11" * 20]).get()
    finally:
        tasks.set_runtime(None)
    assert seen[0][0] == frozenset({41})
    running, idle_for = offer_watch.handling()
    assert running == frozenset() and idle_for < 5
