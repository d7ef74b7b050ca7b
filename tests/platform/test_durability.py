"""The worker daemon across outages, kills, power cuts and a chain that lost blocks: a trained
model outlives a store outage longer than the retries, an offer being checked survives a
kill, a task id given again is trained afresh, a damaged checkpoint is trained again, and
restarts of the whole platform are not deaths of the job (durability audit F3, F4, F10, F8,
F9)."""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path
from typing import Any

import pytest
import torch

from backend.celery_app import make_celery
from backend.chain.platform import OfferState
from backend.settings import Settings
from backend.store import EmbeddedStore, StoreUnavailable
from backend.store.bundle import pull_model
from workers.daemon import tasks
from workers.daemon.handler import MAX_STARTS_WITHOUT_PROGRESS, OfferHandler
from workers.mdrl import checkpoint as ckpt
from workers.mdrl.modelio import load_model
from workers.mdrl.trainingspec import TrainingSpec

from .helpers import TINY_SPEC, post_task

torch.set_num_threads(1)


def handler_for(p, address: str, store, tmp_path: Path, **kw: Any) -> OfferHandler:
    h = OfferHandler(account=p.chain._keys[address], platform=p, store=store,
                     data_dir=tmp_path / "w" / address, **kw)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    return h


class Killed(BaseException):
    """The daemon's process dying (kill -9, OOM): not an exception a job handles."""


class StoreRefusingWrites:
    """An IPFS node being restarted: reads work, the first ``refusals`` writes are refused;
    ``on_refusal`` runs at each (the clock moving on while it is down)."""

    def __init__(self, inner: EmbeddedStore, refusals: int, on_refusal=lambda: None) -> None:
        self.inner, self.left, self.refused, self.on_refusal = inner, refusals, 0, on_refusal

    def add(self, *args: Any, **kw: Any) -> str:
        if self.left > 0:
            self.left -= 1
            self.refused += 1
            self.on_refusal()
            raise StoreUnavailable("http://ipfs:5001", "connection refused")
        return self.inner.add(*args, **kw)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


@pytest.fixture
def eager_daemon(tmp_path: Path):
    """The real Celery job ``drlaas.handle_offer``, run eagerly (each retry at once) with the
    handler the test installs."""
    app = make_celery(Settings(data_dir=tmp_path / "celery"))
    app.set_current()
    yield lambda h: tasks.set_runtime(h)
    tasks.set_runtime(None)


# -- F3: a store outage after training ---------------------------------------------------------
def test_a_trained_model_outlives_a_store_outage_longer_than_the_retries(
    env, tmp_path: Path, eager_daemon
) -> None:
    """Retried past MAX_RETRIES while the deadline allows; given back only once it does not."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester, duration=3600)
    worker = offered[0]
    down = StoreRefusingWrites(store, refusals=tasks.MAX_RETRIES + 3)
    eager_daemon(handler_for(p, worker, down, tmp_path))
    out = tasks.handle_offer.apply(args=[task_id, worker]).get()
    assert down.refused == tasks.MAX_RETRIES + 3  # more tries than MAX_RETRIES, none given up
    assert out["status"] == "submitted", out
    assert p.tmc.offer(task_id, worker)["state"] == OfferState.SUBMITTED

    t2, offered2, _ = post_task(p, store, actors.requester, duration=3600, num_workers=3)
    assert worker in offered2
    late = [0.0]  # the outage lasts until the deadline less its margin has passed
    down = StoreRefusingWrites(store, refusals=10**6, on_refusal=lambda: late.__setitem__(0, 3600))
    h = handler_for(p, worker, down, tmp_path / "late", clock=lambda: time.time() + late[0])
    eager_daemon(h)
    out = tasks.handle_offer.apply(args=[t2, worker]).get()
    assert out["status"] == "failed" and "gave up after" in out["reason"], out
    assert down.refused == tasks.MAX_RETRIES + 1
    assert p.tmc.offer(t2, worker)["state"] == OfferState.FAILED


class StoreDown:
    """An IPFS node that stays down: every read and write is refused."""

    def __init__(self, inner: EmbeddedStore) -> None:
        self.inner, self.refused = inner, 0

    def _refuse(self, *args: Any, **kw: Any) -> Any:
        self.refused += 1
        raise StoreUnavailable("http://ipfs:5001", "connection refused")

    get = add = _refuse

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def test_an_offer_whose_spec_stays_unreadable_is_declined_once_the_retries_run_out(
    env, tmp_path: Path, eager_daemon
) -> None:
    """The store is down while the worker checks an offer: retried with backoff, then the
    offer is declined on chain (the requester can re-offer the slot), not left to expire."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester, duration=3600)
    worker = offered[0]
    down = StoreDown(store)
    eager_daemon(handler_for(p, worker, down, tmp_path))
    out = tasks.handle_offer.apply(args=[task_id, worker]).get()
    assert out["status"] == "declined" and "gave up after" in out["reason"], out
    assert "task spec" in out["reason"] and down.refused == tasks.MAX_RETRIES + 1
    assert p.tmc.offer(task_id, worker)["state"] == OfferState.DECLINED


# -- F4: killed while checking an offer --------------------------------------------------------
def test_a_daemon_killed_while_checking_an_offer_gets_it_again_from_recover(
    env, tmp_path: Path
) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)

    def killed(*args: Any, **kw: Any) -> None:  # while fetching and loading the experts
        raise Killed()

    h._cannot_take = killed  # type: ignore[method-assign]
    with pytest.raises(Killed):
        h.handle(task_id, worker)
    st = h._state(task_id)
    assert st["phase"] == "offered"
    assert st["offer_expiry"] == p.tmc.offer(task_id, worker)["expiry"]
    assert h.active_jobs(exclude=0) == []  # being checked holds no capacity
    queued: list[int] = []
    done = h.recover(lambda tid, w: queued.append(tid))
    assert done["queued"] == [task_id] and queued == [task_id]
    assert h._state(task_id)["phase"] == "offered"
    p.chain.advance_time(700)  # past the 600 s accept window: the offer lapsed unanswered
    done = h.recover(lambda tid, w: queued.append(tid))
    assert done["closed"] == [task_id] and queued == [task_id]
    assert h._state(task_id)["phase"] == "closed"


# -- F10: a task id given again after the chain lost blocks ------------------------------------
def test_a_task_id_given_again_after_a_chain_rollback_is_trained_afresh(
    env, tmp_path: Path
) -> None:
    p, actors, store = env
    before = p.chain.snapshot()
    t_a, offered_a, _ = post_task(p, store, actors.requester, spec={**TINY_SPEC, "seed": 1})
    h = handler_for(p, offered_a[0], store, tmp_path)
    cid_a = h.handle(t_a, offered_a[0])["cid"]
    p.chain.revert(before)  # the chain lost the blocks of task 1 (a power cut, a reorg)
    t_b, offered_b, _ = post_task(p, store, actors.requester, spec={**TINY_SPEC, "seed": 2})
    assert (t_b, offered_b) == (t_a, offered_a)  # same id, same worker, same chain identity
    out = h.handle(t_b, offered_b[0])
    assert out["status"] == "submitted" and out["cid"] != cid_a
    card = load_model(pull_model(store, out["cid"], tmp_path / "b")).card
    assert card["training"]["run"]["seed"] == 2
    kept = [d.name for d in h.job_dir(t_b).parent.iterdir() if d.name != str(t_b)]
    assert len(kept) == 1 and kept[0].startswith(f"{t_b}.replaced-")  # the old job, moved aside
    assert h._state(t_b)["task"]["spec"] != json.loads(
        (h.job_dir(t_b).parent / kept[0] / "state.json").read_text()
    )["task"]["spec"]


# -- F8: checkpoints after a power cut ---------------------------------------------------------
def crash_at_update_3(h: OfferHandler, task_id: int, worker: str) -> None:
    def crash(tid: int, point: dict) -> None:
        if point.get("update") == 3:
            raise Killed()

    h._post_progress = crash  # type: ignore[method-assign]
    with pytest.raises(Killed):
        h.handle(task_id, worker)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]


def test_a_damaged_checkpoint_is_set_aside_and_the_job_trains_again(
    env, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered[0], store, tmp_path, checkpoint_every=1)
    crash_at_update_3(h, task_id, offered[0])
    weights = h.job_dir(task_id) / "run" / "checkpoint" / "state.safetensors"
    weights.write_bytes(weights.read_bytes()[:5])  # what a power cut leaves of an unsynced file
    with caplog.at_level(logging.ERROR, logger="workers.daemon.job"):
        out = h.handle(task_id, offered[0])
    assert out["status"] == "submitted", out
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.SUBMITTED
    assert h._state(task_id)["resumed_from_step"] == 0  # trained from the start
    assert "checkpoint unreadable" in caplog.text and "set aside" in caplog.text


def test_a_checkpoint_left_mid_swap_is_resumed(env, tmp_path: Path) -> None:
    """Killed between the two renames of a checkpoint save: only ``checkpoint.old`` is left,
    whole; the job resumes from it rather than from step 0."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered[0], store, tmp_path, checkpoint_every=1)
    crash_at_update_3(h, task_id, offered[0])
    run = h.job_dir(task_id) / "run"
    (run / "checkpoint").rename(run / "checkpoint.old")
    assert h.handle(task_id, offered[0])["status"] == "submitted"
    assert h._state(task_id)["resumed_from_step"] == 2 * TrainingSpec.from_dict(
        TINY_SPEC).ppo.batch_steps


def test_a_checkpoint_is_on_disk_before_it_replaces_the_last_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    synced: list[str] = []
    real = os.fsync

    def fsync(fd: int) -> None:
        synced.append(Path(os.readlink(f"/proc/self/fd/{fd}")).name)
        real(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    ckpt.save_checkpoint(tmp_path / "checkpoint", {"w": torch.zeros(2)}, {}, {"n": 1})
    files = ["state.safetensors", "env.safetensors", "state.json"]
    assert sorted(synced[:3]) == sorted(files)  # the files, then their directory, then its parent
    assert synced[3:] == ["checkpoint.tmp", tmp_path.name]


# -- F9: restarts of the platform are not deaths of the job ------------------------------------
def test_platform_restarts_before_the_first_checkpoint_do_not_give_the_job_back(
    env, tmp_path: Path
) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]

    def die(tid: int, step: int) -> None:  # the platform killed before the first update
        raise Killed()

    for restart in range(MAX_STARTS_WITHOUT_PROGRESS + 1):  # each a new `drlaas up`
        h = handler_for(p, worker, store, tmp_path, session=f"platform-{restart}")
        h.on_first_step = die
        with pytest.raises(Killed):
            h.handle(task_id, worker)
        assert h._state(task_id)["starts_without_progress"] == 1
    h = handler_for(p, worker, store, tmp_path, session="platform-last")
    assert h.handle(task_id, worker)["status"] == "submitted"
    # deaths of the job's own daemon under one platform still count (the job keeps dying)
    t2, offered2, _ = post_task(p, store, actors.requester, num_workers=3)
    assert worker in offered2
    h.on_first_step = die
    for _ in range(MAX_STARTS_WITHOUT_PROGRESS):
        with pytest.raises(Killed):
            h.handle(t2, worker)
    out = h.handle(t2, worker)
    assert out["status"] == "failed" and "JobKeepsDying" in out["reason"]
