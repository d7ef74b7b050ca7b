"""Held-out crash pass on the worker daemon's upload: a process killed halfway through
publishing its outcome, and a full disk (the store's, or the worker's own while it stages the
outcome), must neither lose the trained model nor fail the job."""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any

import pytest
import torch

from backend.chain.platform import OfferState
from backend.store import EmbeddedStore, StoreUnavailable
from backend.store import embedded as embedded_module
from backend.store import staged as staged_module
from backend.store.bundle import pull_model
from workers.daemon.handler import OfferHandler, Transient

from .helpers import post_task

torch.set_num_threads(1)


class Killed(BaseException):
    """The daemon's process dying (kill -9): not an exception a job handles."""


def handler_for(p: Any, address: str, store: Any, tmp_path: Path) -> OfferHandler:
    h = OfferHandler(account=p.chain._keys[address], platform=p, store=store,
                     data_dir=tmp_path / "w" / address)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    return h


def commitments(p: Any) -> list[Any]:
    return p.tmc.contract.events.CidCommitted().get_logs(from_block=0)


def no_space() -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_an_upload_killed_halfway_publishes_the_same_outcome_after_the_restart(
    env: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Killed after the first piece of the bundle reached the store: the restart publishes the
    same bytes under the one commitment and submits them; nothing is trained again."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)
    real_add = EmbeddedStore.add
    added: list[str] = []

    def add_then_die(self: EmbeddedStore, data: bytes, *, pin: bool = True) -> str:
        if len(added) == 1:
            raise Killed()
        added.append(real_add(self, data, pin=pin))
        return added[-1]

    monkeypatch.setattr(EmbeddedStore, "add", add_then_die)
    with pytest.raises(Killed):
        h.handle(task_id, worker)
    assert h._state(task_id)["phase"] == "trained" and len(added) == 1
    monkeypatch.setattr(EmbeddedStore, "add", real_add)
    trainings: list[int] = []
    real_train = h._train
    monkeypatch.setattr(h, "_train", lambda *a, **kw: trainings.append(1) or real_train(*a, **kw))
    out = h.handle(task_id, worker)
    assert out["status"] == "submitted", out
    assert p.tmc.offer(task_id, worker)["state"] == OfferState.SUBMITTED
    assert len(commitments(p)) == 1  # the same CID: the bundle staged before the kill
    assert trainings == []  # not trained again
    assert (pull_model(store, out["cid"], tmp_path / "pulled") / "model.json").is_file()


def test_a_full_store_disk_at_upload_is_retried_not_a_failed_job(
    env: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The store's disk full when the pin of the bundle is written: that OSError was no
    StoreUnavailable, so the job failed and its trained model was thrown away."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)
    real_write = EmbeddedStore._write_and_rename

    def pins_on_full_disk(self: EmbeddedStore, path: Path, data: bytes) -> None:
        if path.parent.name == "pins" and self is store:
            raise no_space()
        real_write(self, path, data)

    spec_pins = store.pins()
    monkeypatch.setattr(EmbeddedStore, "_write_and_rename", pins_on_full_disk)
    with pytest.raises(Transient, match="No space left"):
        h.handle(task_id, worker)
    assert h._state(task_id)["phase"] == "trained"
    assert p.tmc.offer(task_id, worker)["state"] == OfferState.ACCEPTED
    monkeypatch.setattr(EmbeddedStore, "_write_and_rename", real_write)  # space freed
    out = h.handle(task_id, worker)
    assert out["status"] == "submitted", out
    assert out["cid"] in set(store.pins()) - set(spec_pins)


def test_a_full_disk_on_a_pin_is_a_store_outage(tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    store = EmbeddedStore(tmp_path / "s", fsync=False)
    cid = store.add(b"unpinned", pin=False)
    real_mkstemp = embedded_module.tempfile.mkstemp

    def full(*args: Any, **kw: Any) -> Any:
        if Path(kw["dir"]).name == "pins":
            raise no_space()
        return real_mkstemp(*args, **kw)

    monkeypatch.setattr(embedded_module.tempfile, "mkstemp", full)
    with pytest.raises(StoreUnavailable, match="cannot write the pin of .*No space left"):
        store.add(b"pinned on a full disk")
    with pytest.raises(StoreUnavailable, match=f"cannot write the pin of {cid}"):
        store.pin(cid)


def test_a_full_worker_disk_while_staging_the_outcome_is_retried_not_a_failed_job(
    env: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The worker's own disk full while it saves the staged outcome (before the commitment):
    the job failed and gave its offer back, and a half-written ``.tmp`` piece stayed in the
    outbox. Now it is Transient (retried, the trained model kept), and nothing is left."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)
    outbox = h.job_dir(task_id) / "outbox"
    real_fsync = os.fsync

    def full_in_outbox(fd: int) -> None:
        if os.readlink(f"/proc/self/fd/{fd}").startswith(str(outbox)):
            raise no_space()
        real_fsync(fd)

    monkeypatch.setattr(staged_module.os, "fsync", full_in_outbox)
    with pytest.raises(Transient, match="disk is full"):
        h.handle(task_id, worker)
    assert h._state(task_id)["phase"] == "trained"
    assert p.tmc.offer(task_id, worker)["state"] == OfferState.ACCEPTED
    assert not list(outbox.glob("*.tmp"))
    assert commitments(p) == []  # nothing committed for a bundle that is not saved
    monkeypatch.setattr(staged_module.os, "fsync", real_fsync)
    out = h.handle(task_id, worker)
    assert out["status"] == "submitted", out
