"""A deliberate stop of the worker daemon (SIGTERM, SIGINT: ``systemctl restart``, ``docker
restart``, Ctrl-C) is not a death of its training job: under systemd, or as PID 1 of a
container, every restart has the same ``daemon_session``, so only the record the daemon leaves
when it is asked to stop tells a restart from the job being killed for memory. A SIGKILL
leaves none and still counts toward MAX_STARTS_WITHOUT_PROGRESS."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest
import torch
from celery.signals import worker_shutting_down

from backend.chain.platform import OfferState
from drlaas.commands.scenario import wait_for
from drlaas.commands.up import running_platform
from workers.daemon import tasks
from workers.daemon.handler import MAX_STARTS_WITHOUT_PROGRESS, STOP_MARK, OfferHandler

from .conftest import worker_logs
from .helpers import post_scenario_task, post_task

torch.set_num_threads(1)


class Killed(BaseException):
    """The daemon's process ending (after a stop, or killed): not an exception a job handles."""


def handler_for(p, worker: str, store, tmp_path: Path) -> OfferHandler:  # noqa: ANN001
    h = OfferHandler(account=p.chain._keys[worker], platform=p, store=store,
                     data_dir=tmp_path / "w" / worker, session="one systemd unit")
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    return h


def test_stops_under_one_session_do_not_give_the_job_back_kills_do(env, tmp_path: Path) -> None:
    """Every restart under the same parent (systemd): MAX + 1 stops before the first
    checkpoint and the job still trains; the Celery shutdown signal is what records them."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)
    tasks.set_runtime(h)

    def stopped(tid: int, step: int) -> None:  # Celery's SIGTERM handler, then the SIGKILL
        worker_shutting_down.send(sender="worker@host", sig="SIGTERM", how="Warm", exitcode=0)
        raise Killed()

    def killed(tid: int, step: int) -> None:  # OOM killer: no handler runs
        raise Killed()

    try:
        for _ in range(MAX_STARTS_WITHOUT_PROGRESS + 1):
            h.on_first_step = stopped
            with pytest.raises(Killed):
                h.handle(task_id, worker)
            st = h._state(task_id)
            assert st["starts_without_progress"] == 1, st
            mark = json.loads((h.job_dir(task_id) / STOP_MARK).read_text())
            assert mark["start"] == st["start_id"] and "SIGTERM" in mark["how"]
        h.on_first_step = killed  # a death after stops counts
        with pytest.raises(Killed):
            h.handle(task_id, worker)
        assert h._state(task_id)["starts_without_progress"] == 1
        with pytest.raises(Killed):
            h.handle(task_id, worker)
        assert h._state(task_id)["starts_without_progress"] == 2
        h.on_first_step = None
        assert h.handle(task_id, worker)["status"] == "submitted"
        assert not (h.job_dir(task_id) / STOP_MARK).exists()  # pruned with the job
    finally:
        tasks.set_runtime(None)
    assert h.note_stop("SIGTERM") is None  # no training start: nothing to record


# -- real processes: `drlaas up`'s daemon, SIGTERM (then SIGKILL, as systemd and docker do
# when the warm shutdown outlasts their grace period) and a plain SIGKILL -----------------------
def _state(job: Path) -> dict:
    try:
        return json.loads((job / "state.json").read_text())
    except (OSError, ValueError):
        return {}


def _mark(job: Path) -> dict:
    try:
        return json.loads((job / STOP_MARK).read_text())
    except (OSError, ValueError):
        return {}


def _started(p, job: Path, since: float) -> dict:  # noqa: ANN001
    """The job's state once the running daemon's training start took its first step."""
    proc = p.workers[0].proc
    try:
        return wait_for(
            "the daemon's training start",
            lambda: _state(job),
            lambda st: st.get("pid") == proc.pid and st.get("first_step_at", 0) > since,
            timeout=240,
            every=0.2,
        )
    except TimeoutError as exc:
        raise AssertionError(f"{exc}\n{worker_logs(p)}") from exc


def _restart(p, job: Path) -> dict:  # noqa: ANN001
    since = time.time()
    p.start_worker(0)
    return _started(p, job, since)


def test_sigterm_to_a_real_daemon_is_not_counted_sigkill_is(data_dir: Path) -> None:
    with running_platform(
        workers=1, data_dir=data_dir, worker_args=["--checkpoint-every", "100000"]
    ) as p:  # no checkpoint ever moves: every start gets no further than the one before
        p.wait_registered()
        since = time.time()
        req, task_id, worker, job = post_scenario_task(p, steps=200_000, minutes=10)
        st = _started(p, job, since)
        assert st["starts_without_progress"] == 1

        # systemctl restart: SIGTERM (Celery's warm shutdown goes on training), then SIGKILL
        os.kill(worker.proc.pid, signal.SIGTERM)
        mark = wait_for("the stop's record", lambda: _mark(job),
                        lambda m: m.get("start") == st["start_id"], timeout=30, every=0.1)
        assert "SIGTERM" in mark["how"] and mark["pid"] == worker.proc.pid
        worker.proc.kill()
        worker.proc.wait(timeout=10)
        st = _restart(p, job)
        assert st["starts_without_progress"] == 1, st  # the stopped start was not counted
        assert st["resumed_from_step"] == 0

        # the OOM killer: no record, the start counts
        p.workers[0].proc.kill()
        p.workers[0].proc.wait(timeout=10)
        st = _restart(p, job)
        assert st["starts_without_progress"] == 2, st
        assert p.chain.platform.tmc.offer(task_id, worker.address)["state"] == (
            OfferState.ACCEPTED)
        req.close()
