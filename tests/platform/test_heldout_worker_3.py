"""Held-out attacks on the worker daemon from a hostile requester (the probe of 2026-12-04):
specs that pass every bound and still cost a worker more than it checks for. Each is
declined before acceptance, naming what does not fit, or bounded in what it costs."""

from __future__ import annotations

import csv
import tracemalloc
from collections.abc import Callable
from pathlib import Path

from backend.chain.platform import OfferState
from workers.daemon.handler import DEADLINE_MARGIN_S
from workers.mdrl.curve import MAX_CURVE_POINTS, training_curve
from workers.mdrl.resources import final_evaluation_flops, reference_flops_per_s, update_seconds
from workers.mdrl.trainingspec import TrainingSpec

from .helpers import post_task
from .test_handler import handler_for

#: One tiny update, then a final evaluation of 100 episodes of up to 10,000 steps on 64 x 64
#: (an untrained team idles: every episode runs to max_steps): minutes by the resource model.
LONG_EVALUATION = {
    "env": {"rows": 64, "cols": 64, "agents": 8, "max_steps": 10_000, "idle_limit": 10_000},
    "observation": {"kind": "odmtl", "window": 3},
    "budget": {"steps": 128},
    "seed": 1,
    "algorithm": {"ppo": {"num_envs": 8, "horizon": 16, "update_epochs": 1}},
}


def test_an_offer_whose_deadline_cannot_hold_the_final_evaluation_is_declined(
    env, tmp_path: Path
) -> None:
    """The deadline check counted one PPO update only, but the final evaluation runs after
    the last update whatever the time left (``Trainer.train``): a spec of tiny updates and
    episodes of 10,000 steps on a large grid was accepted with minutes to go and delivered
    after its deadline (the task lost, the worker busy meanwhile). Now both must fit."""
    p, actors, store = env
    spec = TrainingSpec.from_dict(LONG_EVALUATION)
    update_s = update_seconds(spec)
    final_s = final_evaluation_flops(spec) / reference_flops_per_s()
    assert final_s > 60 and update_s < 1  # what the attack relies on
    task_id, offered, _ = post_task(p, store, actors.requester, spec=LONG_EVALUATION)
    h = handler_for(p, offered[0], store, tmp_path)
    deadline = int(p.tmc.task(task_id)["deadline"])
    left_s = update_s + final_s / 2  # many updates' time, half the evaluation's
    h.clock = lambda: deadline - DEADLINE_MARGIN_S - left_s
    reason = h._cannot_take(task_id, spec, actors.requester, deadline=deadline)
    assert reason is not None and reason.startswith("deadline: one PPO update and the final "
                                                    "evaluation"), reason
    assert "max_steps = 10000" in reason and f"leaves {left_s:.0f} s" in reason, reason
    out = h.handle(task_id, offered[0])
    assert out["status"] == "declined" and out["reason"] == reason, out
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED


#: Updates of one env step each (``num_envs`` 1, ``horizon`` 1) run ~300 a second here: a
#: week's budget is ~10^8 rows of metrics.csv. A tenth of a million is enough to tell O(1)
#: memory from memory per row.
MANY_UPDATES = 100_000
#: What reading or trimming metrics.csv may hold at once (the rows above held ~40-150 MiB).
FEW_BYTES = 4 * 2**20


def _metrics_of_many_updates(path: Path) -> Path:
    """A job's metrics.csv after MANY_UPDATES updates of one env step each."""
    from workers.mdrl.train import METRIC_COLUMNS

    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(METRIC_COLUMNS)
        for i in range(1, MANY_UPDATES + 1):
            w.writerow([i, i, i / 300, 300.0, 1e-3, 0.1, -0.01, 0.5, 0.9, 0.0, 0.0, 0.1,
                        1, i % 2, 7.0, 6.0, 3.0, "", "", ""])
    return path


def _peak_bytes(fn: Callable[[], object]) -> int:
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_the_curve_of_a_run_of_many_tiny_updates_is_read_in_bounded_memory(
    tmp_path: Path,
) -> None:
    """A spec may ask for one env step per update and a week of training: the card's curve
    (``attach_curve``, after the last update) held every metrics.csv row at once, more
    memory than the resource model counts for the run, so the job died after all its
    training, at each start, and was given back. Now the file is read a row at a time."""
    metrics = _metrics_of_many_updates(tmp_path / "metrics.csv")
    curve: dict = {}
    peak = _peak_bytes(lambda: curve.update(training_curve(metrics)))
    assert peak < FEW_BYTES, f"{peak / 2**20:.1f} MiB to read {MANY_UPDATES} rows"
    points = curve["points"]
    assert curve["updates"] == MANY_UPDATES and len(points) == MAX_CURVE_POINTS
    assert points[-1]["step"] == MANY_UPDATES
    assert points[0]["step"] == MANY_UPDATES // MAX_CURVE_POINTS
    assert points[0]["success"] == 0.5 and points[0]["time"] == 7.0


def test_a_resumed_run_of_many_tiny_updates_trims_its_metrics_in_bounded_memory(
    tmp_path: Path,
) -> None:
    """On resume the trainer drops the metrics.csv rows after its checkpoint: it read the
    whole file into memory first (a row of 20 columns as a list of strings, ~1.5 KiB), at
    every start of a job of many tiny updates. Now a row at a time."""
    from workers.mdrl.observations import ObservationSpec
    from workers.mdrl.ppo import PPOConfig
    from workers.mdrl.spec import EnvSpec
    from workers.mdrl.train import RunConfig, Trainer

    run = RunConfig(total_steps=8, eval_episodes=2, tensorboard=False, progress=False)
    out = tmp_path / "run"
    trainer = Trainer(EnvSpec(rows=4, cols=4, agents=1), ObservationSpec(kind="dmtl"),
                      PPOConfig(num_envs=1, horizon=1, update_epochs=1, num_minibatches=1),
                      run, out=out)
    metrics = _metrics_of_many_updates(out / "metrics.csv")
    trainer.update_idx = MANY_UPDATES // 2  # the checkpoint resumed from
    peak = _peak_bytes(trainer._open_outputs)
    assert peak < FEW_BYTES, f"{peak / 2**20:.1f} MiB to trim {MANY_UPDATES} rows"
    with metrics.open(newline="") as f:
        rows = list(csv.reader(f))
    assert len(rows) == 1 + MANY_UPDATES // 2 and rows[-1][0] == str(MANY_UPDATES // 2)


def test_a_task_described_by_4_kb_of_text_is_declined_with_a_short_reason(
    env, tmp_path: Path
) -> None:
    """The spec CID is the task's on-chain description, any text a requester's own addTask
    writes: the decline's reason quoted it whole (100 KB into the reason state.json, the log
    and the Celery result keep, for every offer of it; the chain now takes at most
    MAX_DESCRIPTION_BYTES). It names it cut short, with its length."""
    p, actors, store = env
    cap = p.tmc.call("MAX_DESCRIPTION_BYTES")
    description = "Qm" + "x" * (cap - 2)
    task_id, _ = p.tmc.add_task(actors.requester, domain=0, num_workers=1, reward=10**15,
                                duration=3600, description=description)
    offered, _ = p.tmc.allocate(actors.requester, task_id)
    h = handler_for(p, offered[0], store, tmp_path)
    out = h.handle(task_id, offered[0])
    assert out["status"] == "declined", out
    assert out["reason"].startswith("spec: task spec 'Qmxxx") and len(out["reason"]) < 1000, \
        out["reason"][:300]
    assert f"({cap} characters)" in out["reason"] and "invalid CID" in out["reason"]
    assert h._state(task_id)["reason"] == out["reason"]
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED
