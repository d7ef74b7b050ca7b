"""Held-out worker audit of 2026-12-04 (4): an offer past its deadline is declined before any
expert model is fetched, and a job of tiny updates does not rewrite its checkpoint every few
milliseconds, yet still resumes after a kill."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from backend.chain.platform import OfferState
from backend.store.bundle import upload_model
from workers.daemon import handler as handler_module
from workers.daemon import job as jobs
from workers.daemon.handler import DEADLINE_MARGIN_S
from workers.mdrl import train as train_module
from workers.mdrl.resources import final_evaluation_seconds, update_seconds
from workers.mdrl.trainingspec import TrainingSpec

from .helpers import TINY_SPEC, post_task
from .test_handler import handler_for

EXPERT = Path(__file__).resolve().parents[2] / "models" / "odmtl-2a"  # window 5, fits 6x6
FETCHES = ("offer_fetch_bytes", "check_expert_card", "check_walls_cae_card", "fetch_experts",
           "fetch_walls_cae")


def _expert_spec(cid: str) -> dict:
    return {**TINY_SPEC, "experts": [cid], "algorithm": {"demonstration": {"rate": 0.5}}}


def _record_fetches(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every expert download of the offer check (manifests, cards, weights), recorded."""
    calls: list[str] = []
    for name in FETCHES:
        real = getattr(handler_module, name)

        def spy(*args, _name=name, _real=real, **kw):
            calls.append(_name)
            return _real(*args, **kw)

        monkeypatch.setattr(handler_module, name, spy)
    return calls


@pytest.mark.parametrize("late", ["passed", "no room for one update"])
def test_an_offer_past_its_deadline_is_declined_before_any_expert_is_fetched(
    env, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, late: str
) -> None:
    """The offer check fetched each expert's manifest and card (up to
    ``max_offer_fetch_bytes``, 256 MiB, of a requester's choosing) before it looked at the
    deadline: an offer whose deadline had passed, or could not hold one update and the final
    evaluation, still cost the worker those downloads. Now the deadline comes first."""
    p, actors, store = env
    cid = upload_model(store, EXPERT)
    doc = _expert_spec(cid)
    spec = TrainingSpec.from_dict(doc)
    task_id, offered, _ = post_task(p, store, actors.requester, spec=doc)
    h = handler_for(p, offered[0], store, tmp_path)
    deadline = int(p.tmc.task(task_id)["deadline"])
    need_s = update_seconds(spec) + final_evaluation_seconds(spec)
    left_s = -60.0 if late == "passed" else need_s / 2
    h.clock = lambda: deadline - DEADLINE_MARGIN_S - left_s
    calls = _record_fetches(monkeypatch)

    out = h.handle(task_id, offered[0])
    assert out["status"] == "declined", out
    assert out["reason"].startswith("deadline: one PPO update and the final evaluation"), out
    assert calls == [], f"fetched {calls} for an offer it could not take"
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED
    assert not (h.job_dir(task_id) / "experts").exists()


def test_an_offer_in_time_still_checks_its_experts(
    env, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The same offer with its deadline ahead is checked as before: manifests, cards and
    weights fetched before it is accepted (the order of the other checks is kept)."""
    p, actors, store = env
    cid = upload_model(store, EXPERT)
    doc = _expert_spec(cid)
    task_id, offered, _ = post_task(p, store, actors.requester, spec=doc)
    h = handler_for(p, offered[0], store, tmp_path)
    calls = _record_fetches(monkeypatch)
    reason = h._cannot_take(task_id, TrainingSpec.from_dict(doc), actors.requester,
                            deadline=int(p.tmc.task(task_id)["deadline"]))
    assert reason is None
    assert calls == ["offer_fetch_bytes", "check_expert_card", "fetch_experts"]


#: Updates of one env step each: what a spec may ask for (num_envs 1, horizon 1).
TINY_UPDATES = {
    "env": {"rows": 4, "cols": 4, "agents": 1, "max_steps": 20, "idle_limit": 20},
    "observation": {"kind": "odmtl", "window": 3},
    "algorithm": {"ppo": {"num_envs": 1, "horizon": 1, "update_epochs": 1,
                          "num_minibatches": 1}},
    "budget": {"steps": 40},
    "seed": 5,
}


def _count_checkpoints(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    saved: list[int] = []
    real = jobs.JobTrainer.save_checkpoint

    def save(self, path):
        saved.append(self.update_idx)
        return real(self, path)

    monkeypatch.setattr(jobs.JobTrainer, "save_checkpoint", save)
    return saved


def test_a_job_of_tiny_updates_checkpoints_by_wall_clock_not_every_update(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A checkpoint every ``checkpoint_every`` updates was, for updates of one env step, ~100
    fsynced checkpoint writes a second for up to a week. Now a job writes at most
    ``checkpoint_burst`` at once and then one per CHECKPOINT_INTERVAL_S: with the clock
    standing still, 40 updates checkpointed every update give the burst and the last one."""
    spec = TrainingSpec.from_dict(TINY_UPDATES)
    assert spec.ppo.batch_steps == 1
    monkeypatch.setattr(train_module, "_monotonic", lambda: 1000.0, raising=False)
    saved = _count_checkpoints(monkeypatch)
    jobs.run_job(spec, tmp_path / "job", checkpoint_every=1)
    burst = getattr(jobs.JobTrainer, "checkpoint_burst", 10)
    assert saved == [*range(1, burst + 1), 40], saved


def test_a_killed_job_of_tiny_updates_loses_at_most_an_interval_of_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Resumability is kept: with a quarter of the interval passing per update, a job
    checkpoints every 4 updates once its burst is spent; killed at update 30 it resumes from
    update 26 at worst, and finishes with every step of its budget."""
    spec = TrainingSpec.from_dict(TINY_UPDATES)
    clock = iter(range(10**6))
    quarter = getattr(jobs, "CHECKPOINT_INTERVAL_S", 30.0) / 4
    monkeypatch.setattr(train_module, "_monotonic", lambda: next(clock) * quarter,
                        raising=False)
    saved = _count_checkpoints(monkeypatch)

    class Killed(BaseException):
        pass

    def kill_at_30(point: dict) -> None:
        if point["update"] == 30:
            raise Killed()

    job = tmp_path / "job"
    with pytest.raises(Killed):
        jobs.run_job(spec, job, checkpoint_every=1, on_progress=kill_at_30)
    burst = getattr(jobs.JobTrainer, "checkpoint_burst", 10)
    assert len(saved) < 30 - burst and saved[:burst] == list(range(1, burst + 1)), saved
    state = json.loads((jobs.run_dir(job) / "checkpoint" / "state.json").read_text())
    assert 26 <= state["counters"]["update"] < 30, state["counters"]
    model, _ = jobs.run_job(spec, job, checkpoint_every=1)
    card = json.loads((model / "model.json").read_text())
    assert card["training"]["env_steps"] == 40
