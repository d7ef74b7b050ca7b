"""Held-out worker audit of 2026-12-05 (5): task specs the spec validation accepts and the
worker then cannot train, hostile expert bundles, and crashes at awkward moments. Each offer
is declined naming what is wrong (not accepted and failed on chain at the worker's
reputation), and nothing trained is lost."""

from __future__ import annotations

from pathlib import Path

import pytest

from backend.chain.platform import OfferState
from workers.mdrl.trainingspec import SpecError, TrainingSpec

from .helpers import TINY_SPEC, post_task
from .test_handler import handler_for
from .test_heldout_worker_4 import TINY_UPDATES as TINY_UPDATES_40

#: CMTL's joint actor has A**N outputs: 5 actions (4 moves + idle) and 9 agents is 5**9 ~ 2M,
#: over the observer's MAX_JOINT_ACTIONS (2**20), yet within every per-field bound of a task
#: spec and, by the resource model, ~2 GiB: a worker's memory check passed it.
CMTL_TOO_MANY_AGENTS = {
    "env": {"rows": 7, "cols": 8, "agents": 9},
    "observation": {"kind": "cmtl"},
    "budget": {"steps": 256},
    "seed": 2,
}


def test_a_cmtl_spec_whose_joint_actions_no_trainer_builds_is_declined(
    env, tmp_path: Path
) -> None:
    """The spec parser bounded agents (16) and grid, not CMTL's joint action space A**N, which
    the trainer refuses past 2**20 (``observations.check_joint_actions``) as it builds the
    observer. The worker accepted such an offer (it fit the memory estimate and the deadline)
    and the job then failed at once, given back with abandonOffer: a requester could post it
    through the gateway and have every worker it reached fail a job. Now the parser refuses
    it (the gateway does not take it), and a worker offered it from a direct write declines,
    naming the joint actions."""
    p, actors, store = env
    with pytest.raises(SpecError, match="joint actions"):
        TrainingSpec.from_dict(CMTL_TOO_MANY_AGENTS)
    task_id, offered, _ = post_task(p, store, actors.requester, spec=CMTL_TOO_MANY_AGENTS)
    h = handler_for(p, offered[0], store, tmp_path, memory_bytes=16 * 2**30)
    out = h.handle(task_id, offered[0])
    assert out["status"] == "declined", out
    assert out["reason"].startswith("observation.kind: ") and "5**9" in out["reason"], out
    assert "joint actions" in out["reason"], out
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED


@pytest.mark.parametrize("agents, moves", [(8, 4), (6, 8)])
def test_cmtl_at_the_joint_action_bound_is_still_taken(agents: int, moves: int) -> None:
    """5**8 and 9**6 are within MAX_JOINT_ACTIONS: the parser takes such specs."""
    spec = TrainingSpec.from_dict({
        "env": {"rows": 7, "cols": 8, "agents": agents, "moves": moves},
        "observation": {"kind": "cmtl"}, "budget": {"steps": 256},
    })
    assert spec.env.num_actions ** spec.env.agents <= 2**20


#: Updates of one env step each (``num_envs`` 1, ``horizon`` 1): ~300 a second.
TINY_UPDATES = {**TINY_UPDATES_40, "budget": {"steps": 300}}


def test_a_job_of_tiny_updates_posts_a_thinned_live_curve_that_ends_with_the_run(
    env, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A job posted a progress point per update; the gateway keeps 5,000 per worker and task
    (409 ``progress_full``) and a spec of one env step per update makes ~300 a second for
    up to a week: the live curve stopped after the first ~20 s of training, and every later
    update still cost the gateway a refused request. Scaled down here (LIVE_POINTS 20 instead
    of 2,000): 300 updates post the first few, one every ``stride`` updates, and the last."""
    from workers.daemon import progress_sender

    monkeypatch.setattr(progress_sender, "LIVE_POINTS", 20, raising=False)
    monkeypatch.setattr(progress_sender, "FIRST_POINTS", 5, raising=False)
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester, spec=TINY_UPDATES)
    h = handler_for(p, offered[0], store, tmp_path)
    posted: list[dict] = []
    h._post_progress = lambda tid, point: posted.append(point)  # type: ignore[method-assign]
    assert h.handle(task_id, offered[0])["status"] == "submitted"
    updates = [pt["update"] for pt in posted]
    assert len(updates) <= 5 + 2 * 20 + 1, f"{len(updates)} points posted for 300 updates"
    assert updates[:5] == [1, 2, 3, 4, 5] and updates[-1] == 300, updates
    assert max(b - a for a, b in zip(updates, updates[1:], strict=False)) <= 15, updates
    assert posted[-1]["step"] == 300
    kept = (h.job_dir(task_id) / "progress.jsonl").read_text().splitlines()
    assert len(kept) == 300  # the job's own record keeps every point


def test_a_week_of_tiny_updates_stays_under_the_gateways_cap_and_spans_the_week() -> None:
    """The thinning of the largest budget a spec allows (a week, 10^9 one-step updates): at
    most the gateway's 5,000 points, spread over the whole week."""
    from workers.daemon.progress_sender import LiveCurve

    week_s = 7 * 24 * 3600.0
    spec = TrainingSpec.from_dict({**TINY_UPDATES,
                                   "budget": {"steps": 10**9, "minutes": week_s / 60}})
    curve = LiveCurve.for_job(spec, week_s)
    n = 1_000_000  # one point in every ~180 updates of the week's ~1.8e8
    kept = [i for i in range(1, n + 1)
            if curve.keep({"update": i * 181, "step": i * 181, "wall_time": i * week_s / n})]
    assert 1_000 <= len(kept) <= 5_000, len(kept)
    assert kept[-1] * week_s / n > week_s - 3600  # points into the week's last hour


#: One env step per update for a day: ~300 updates a second, each a metrics row and a
#: progress line on the worker's disk.
TINY_UPDATES_FOR_A_DAY = {**TINY_UPDATES, "budget": {"minutes": 24 * 60}}


def test_a_spec_whose_logs_exceed_the_workers_disk_is_declined(env, tmp_path: Path) -> None:
    """A day of one-step updates appends a metrics row and a progress line per update, GBs
    that no memory or time check saw: a worker with 1 GiB free took the task and filled its
    disk. It is declined naming the disk; a usual spec on the same disk is taken, and the
    same tiny spec on a disk of 1 TiB too."""
    from workers.mdrl.resources import log_bytes

    p, actors, store = env
    day = TrainingSpec.from_dict(TINY_UPDATES_FOR_A_DAY)
    assert log_bytes(day, 86_400.0) > 2**30
    task_id, offered, _ = post_task(p, store, actors.requester, spec=TINY_UPDATES_FOR_A_DAY,
                                    duration=86_400)
    small = handler_for(p, offered[0], store, tmp_path / "small", disk_free=lambda _: 2**30)
    out = small.handle(task_id, offered[0])
    assert out["status"] == "declined", out
    assert out["reason"].startswith("spec_exceeds_worker_disk"), out
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED

    usual, offered2, _ = post_task(p, store, actors.requester)
    fine = handler_for(p, offered2[0], store, tmp_path / "fine", disk_free=lambda _: 2**30)
    deadline = p.tmc.task(usual)["deadline"]
    assert fine._disk_short(TrainingSpec.from_dict(TINY_SPEC), deadline) is None
    big = handler_for(p, offered2[0], store, tmp_path / "big", disk_free=lambda _: 2**40)
    assert big._disk_short(day, int(big.clock()) + 86_400) is None
