"""A resumable training job: the MDRL trainer with a budget, checkpoints and progress hooks.

Layout of a job directory ``<worker data>/jobs/<task_id>/``: ``run/`` is the trainer's output
(``checkpoint/`` every ``checkpoint_every`` updates and at most every CHECKPOINT_INTERVAL_S
seconds, ``metrics.csv``, ``model/`` at the end,
``best/`` the best evaluated policy when the spec's ``selection.keep_best`` asks for it),
``progress.jsonl`` the points posted to the gateway, ``experts/<CID>/`` the verified expert
models of an MEDC task (``workers.daemon.experts``); a finished job keeps its model, metrics
and progress, not its checkpoint and experts (``OfferHandler._prune``). A job started again in
the same directory resumes from its last checkpoint (the trainer restores weights, optimiser,
RNGs and env state, and the DC / MEDC selector's state: roulette-wheel RNG, each env's guiding
expert, counters), so the continued run is the run that would have happened without the
interruption.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

from workers.daemon.experts import ExpertFetchError, load_job_experts, load_walls_encoder
from workers.mdrl.checkpoint import restore_swapped
from workers.mdrl.curve import attach_curve
from workers.mdrl.train import RunConfig, Trainer
from workers.mdrl.trainingspec import TrainingSpec

log = logging.getLogger(__name__)

#: Updates between checkpoints: a killed worker loses at most this many updates of work, or
#: about CHECKPOINT_INTERVAL_S seconds of it and the update in progress, whichever is more.
CHECKPOINT_EVERY = 2
#: Seconds per checkpoint a job may write on average (``Trainer.checkpoint_interval_s``: after
#: the first ``Trainer.checkpoint_burst`` checkpoints of a process, at most one per interval).
#: A spec may ask for updates of one env step (``num_envs`` 1, ``horizon`` 1: ~7 ms each), and
#: a checkpoint every CHECKPOINT_EVERY updates was then ~100 fsynced checkpoint writes a
#: second (each ~30 ms: most of the job's time went to rewriting its checkpoint) for up to the
#: week of ``budget.minutes``. A wall-clock floor bounds that to one write per 30 s whatever
#: the update size and keeps resumability: a killed job loses at most about 30 s of training
#: (and the update in progress), the order of the daemon's DEADLINE_MARGIN_S; jobs whose
#: updates take 15 s or more checkpoint every CHECKPOINT_EVERY updates as before, and so do
#: the first updates of every start (the burst: a process that dies early still shows
#: progress). Chosen over a minimum batch per update in the spec's bounds (it would refuse
#: specs that are valid and cheap when short, and bound nothing in time) and over counting
#: disk in the resource model (checkpoints replace each other: their cost is the write rate,
#: not space).
CHECKPOINT_INTERVAL_S = 30.0

ProgressHook = Callable[[dict[str, Any]], None]

#: Seconds the trial of an expert-guided job's experts (``attach_expert_review``) may need: a
#: job that trained to within this of its deadline delivers without the trial.
TRIAL_TIME_S = 60.0


class JobTrainer(Trainer):
    """The MDRL trainer with two hooks: ``on_first_step`` (before the first env step of this
    process, for the submission-to-training latency) and ``on_row`` (after each update, with
    ``guided_share`` in an expert-guided run)."""

    on_row: ProgressHook | None = None
    on_first_step: Callable[[int], None] | None = None
    checkpoint_interval_s = CHECKPOINT_INTERVAL_S
    _started = False
    _episodes_seen: tuple[int, int] | None = None

    def collect(self) -> dict[str, float]:
        if not self._started:
            self._started = True
            self._episodes_seen = _episode_counts(self.selector)  # a resumed run's so far
            if self.on_first_step is not None:
                self.on_first_step(self.global_step)
        return super().collect()

    def _log(self, row: dict[str, Any]) -> None:
        super()._log(row)
        if self.on_row is not None:
            self.on_row({**row, **self._guidance()})

    def _guidance(self) -> dict[str, float]:
        """``guided_share``: of the episodes begun since the last row, the share an expert
        guided (DC / MEDC, R_E; falls with the credit rule or a rate schedule), for the live
        curve; nothing without experts or when no episode began."""
        now = _episode_counts(self.selector)
        if now is None:
            return {}
        before = self._episodes_seen if self._episodes_seen is not None else now
        self._episodes_seen = now
        guided, own = now[0] - before[0], now[1] - before[1]
        return {"guided_share": guided / (guided + own)} if guided + own > 0 else {}


def _episode_counts(selector: Any) -> tuple[int, int] | None:
    """(expert-guided, own) episodes begun so far of a DC / MEDC selector; None otherwise."""
    if not (hasattr(selector, "episodes") and hasattr(selector, "own_episodes")):
        return None
    return int(selector.episodes.sum()), int(selector.own_episodes)


def progress_point(row: dict[str, Any]) -> dict[str, Any]:
    """One point of the live curve from a metrics row: {step, success, time, cost, ...}
    (success rate, mean episode length and moving cost of the update's finished episodes)."""

    def num(key: str) -> float | None:
        v = row.get(key)
        if v is None or (isinstance(v, float) and math.isnan(v)):
            return None
        return float(v)

    point = {
        "step": int(row["global_step"]),
        "update": int(row["update"]),
        "success": num("success"),
        "time": num("episode_length"),
        "cost": num("episode_cost"),
        "return": num("episode_return"),
        "eval_success": num("eval_success"),
        "guided_share": num("guided_share"),
        "wall_time": num("wall_time"),
    }
    # the gateway takes numbers only: a metric not measured in this update is left out
    return {k: v for k, v in point.items() if v is not None or k in ("success", "time", "cost")}


def run_dir(job_dir: str | Path) -> Path:
    return Path(job_dir) / "run"


def delivered_model(job_dir: str | Path, spec: TrainingSpec) -> Path:
    """The model directory a job delivers: the run's final policy, or with the spec's
    ``selection.keep_best`` the best evaluated one (``Trainer.keep_if_best``)."""
    return run_dir(job_dir) / ("best" if spec.selection.keep_best else "model")


#: Written by ``run_job`` once the delivered model is complete (weights, card with its curve):
#: a job killed after that, before its handler recorded it, is not trained again.
FINISHED_MARK = "delivered.json"


def finished_training(job_dir: str | Path, spec: TrainingSpec) -> Path | None:
    """The delivered model of a job whose training ran to the end (``FINISHED_MARK`` names
    it and its card is there), else None."""
    try:
        name = json.loads((Path(job_dir) / FINISHED_MARK).read_text())["model"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    model = delivered_model(job_dir, spec)
    return model if name == model.name and (model / "model.json").is_file() else None


def has_checkpoint(job_dir: str | Path) -> bool:
    return (run_dir(job_dir) / "checkpoint" / "state.json").is_file()


def set_checkpoint_aside(job_dir: str | Path, exc: BaseException) -> Path:
    """Move an unreadable checkpoint to ``checkpoint.unreadable-<time>`` (logged) so the job
    trains from the start instead of failing: a power cut can damage a checkpoint, and a job
    given back loses the task, where training again may still meet the deadline."""
    out = run_dir(job_dir)
    kept = out / f"checkpoint.unreadable-{int(time.time())}"
    n = 1
    while kept.exists():
        kept, n = out / f"checkpoint.unreadable-{int(time.time())}-{n}", n + 1
    os.replace(out / "checkpoint", kept)
    log.error("%s: checkpoint unreadable (%s: %s), set aside as %s; training from the start",
              out, type(exc).__name__, exc, kept.name)
    return kept


def make_selector(spec: TrainingSpec, experts: dict[str, Path] | None) -> Any:
    """The DC / MEDC selector (Alg. 4.1 / 5.1, ``medc.DemonstrationSelector``) of a spec that
    names experts, its models loaded from ``experts`` ({CID: verified directory}) and named by
    CID; None for plain PPO. Built the same way on resume, so the checkpoint's selector state
    (which records the experts by CID) loads into it."""
    demo = spec.demonstration()
    if demo is None:
        return None
    from workers.mdrl.medc import DemonstrationSelector

    missing = [ref for ref in demo.experts if ref not in (experts or {})]
    if missing:
        raise ValueError(f"experts {missing} were not fetched for this job")
    loaded = load_job_experts(demo.experts, experts or {}, spec.env, spec.seed)
    return DemonstrationSelector.from_config(demo, spec.env, seed=spec.seed, experts=loaded)


def load_job_models(
    spec: TrainingSpec, experts: dict[str, Path] | None, walls_cae: Path | None
) -> tuple[Any, Any]:
    """What a job of ``spec`` loads besides its own nets: (its DC / MEDC selector with the
    experts, :func:`make_selector`; the walls encoder of ``observation.walls_embedding``,
    from its verified directory ``walls_cae``), None for what the spec does not name."""
    selector = make_selector(spec, experts)
    ref = spec.observation.walls_embedding
    if ref is None:
        return selector, None
    if walls_cae is None:
        raise ValueError(f"walls CAE {ref} was not fetched for this job")
    return selector, load_walls_encoder(ref, walls_cae)


def check_job_models(
    spec: TrainingSpec, experts: dict[str, Path] | None, walls_cae: Path | None
) -> None:
    """Load what :func:`make_trainer` loads besides the job's own nets and drop it: each
    expert through its adapter onto the task (its card's input shape, its weights against
    its card), the walls encoder against the task's grid and ``walls_embedding_size`` (the
    observer the trainer builds checks them). ExpertFetchError names the CID. A worker runs
    this before it accepts an offer: a model no run could use is then a decline, not a job
    failed on chain."""
    _, encoder = load_job_models(spec, experts, walls_cae)
    if encoder is None:
        return
    from workers.mdrl.observations import make_observer

    try:
        make_observer(spec.env, spec.observation, encoder)
    except ValueError as exc:
        raise ExpertFetchError(
            str(spec.observation.walls_embedding), f"cannot serve this task: {exc}"
        ) from None


def make_trainer(
    spec: TrainingSpec,
    job_dir: str | Path,
    *,
    minutes: float | None = None,
    minutes_left: float | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
    checkpoint_interval_s: float = CHECKPOINT_INTERVAL_S,
    experts: dict[str, Path] | None = None,
    walls_cae: Path | None = None,
) -> JobTrainer:
    """A trainer for ``spec`` in ``job_dir``: resumed from its checkpoint when there is one.
    ``minutes`` overrides the spec's time budget (training time over all of the job's runs);
    ``minutes_left`` is the wall time this process may still train (a task deadline): the
    budget becomes the training time so far plus that, within the spec's;
    ``experts`` maps the spec's expert CIDs to their verified directories; ``walls_cae`` is
    the verified directory of the spec's ``observation.walls_embedding`` CID; a checkpoint
    comes every ``checkpoint_every`` updates and at most one per ``checkpoint_interval_s``
    seconds (CHECKPOINT_INTERVAL_S)."""
    selector, encoder = load_job_models(spec, experts, walls_cae)
    out = run_dir(job_dir)
    budget_minutes = spec.minutes if minutes is None else minutes
    run = spec.run_config(
        tensorboard=False,
        progress=False,
        threads=1,
        checkpoint_every=checkpoint_every,
        minutes=budget_minutes,
    )
    if restore_swapped(run_dir(job_dir) / "checkpoint"):  # killed between atomic_dir's renames
        log.warning("%s: resuming from checkpoint.old", run_dir(job_dir))
    trainer: JobTrainer | None = None
    if has_checkpoint(job_dir):  # the spec's run config, also over a checkpoint's older one
        try:
            trainer = cast(
                JobTrainer,
                JobTrainer.resume(
                    out, out=out, run_overrides=run.to_dict(), selector=selector,
                    walls_encoder=encoder,
                ),
            )
        except (OSError, ValueError, KeyError, TypeError) as exc:  # damaged: train afresh
            set_checkpoint_aside(job_dir, exc)
            selector, encoder = load_job_models(spec, experts, walls_cae)  # resume used them
    if trainer is None:
        trainer = JobTrainer(
            spec.env, spec.observation, spec.ppo, run, out=out, selector=selector,
            walls_encoder=encoder,
        )
    trainer.checkpoint_interval_s = checkpoint_interval_s
    if minutes_left is not None:  # Trainer budgets count the elapsed time of earlier runs
        total = trainer.elapsed / 60.0 + minutes_left
        if trainer.run.minutes is not None:
            total = min(trainer.run.minutes, total)
        trainer.run = dataclasses.replace(trainer.run, minutes=total)
    return trainer


def run_job(
    spec: TrainingSpec,
    job_dir: str | Path,
    *,
    on_progress: ProgressHook | None = None,
    on_first_step: Callable[[int], None] | None = None,
    minutes: float | None = None,
    minutes_left: float | None = None,
    checkpoint_every: int = CHECKPOINT_EVERY,
    checkpoint_interval_s: float = CHECKPOINT_INTERVAL_S,
    experts: dict[str, Path] | None = None,
    walls_cae: Path | None = None,
) -> tuple[Path, dict[str, Any]]:
    """Train (or finish training) ``spec`` in ``job_dir``; returns (the delivered model dir,
    its metrics: the last update's, with the delivered policy's evaluation).

    Each update appends a progress point to ``progress.jsonl`` and calls ``on_progress``."""
    started = time.perf_counter()  # minutes_left counts from here (loading the models too)
    job = Path(job_dir)
    job.mkdir(parents=True, exist_ok=True)
    (job / FINISHED_MARK).unlink(missing_ok=True)  # this run delivers anew
    trainer = make_trainer(
        spec,
        job,
        minutes=minutes,
        minutes_left=minutes_left,
        checkpoint_every=checkpoint_every,
        checkpoint_interval_s=checkpoint_interval_s,
        experts=experts,
        walls_cae=walls_cae,
    )
    points = job / "progress.jsonl"

    def on_row(row: dict[str, Any]) -> None:
        point = progress_point(row)
        with points.open("a") as f:
            f.write(json.dumps(point) + "\n")
        if on_progress is not None:
            on_progress(point)

    trainer.on_row = on_row
    trainer.on_first_step = on_first_step
    t0 = time.perf_counter()
    metrics = trainer.train()
    model = delivered_model(job, spec)
    attach_curve(model, run_dir(job) / "metrics.csv")  # the card's training curve
    left_s = (None if minutes_left is None
              else minutes_left * 60.0 - (time.perf_counter() - started))
    if left_s is not None and left_s < TRIAL_TIME_S:
        log.warning("%s: no expert review in the card: the deadline is too near", model)
    else:
        attach_expert_review(model, spec, experts, seconds=left_s)
    mark = job / (FINISHED_MARK + ".tmp")
    mark.write_text(json.dumps({"model": model.name, "global_step": trainer.global_step}))
    os.replace(mark, job / FINISHED_MARK)
    chosen = trainer.best or {}  # set only when the spec keeps the best evaluated policy
    return model, {
        **metrics,
        **trainer.last_eval,
        **{k: v for k, v in chosen.items() if k.startswith("eval_")},
        "job_seconds": time.perf_counter() - t0,
        "resumed_from_update": None,
    }


def attach_expert_review(model: Path, spec: TrainingSpec, experts: dict[str, Path] | None,
                         *, seconds: float | None = None) -> None:
    """The requester's evidence for reviewing the experts of an expert-guided job: each one
    followed by the team on the task (``workers.mdrl.review``), in the delivered card. A
    failure here costs the evidence, not the outcome (the model is trained and kept); so does
    a trial longer than ``seconds`` (the time left before the deadline's margin): 100
    episodes of up to 10,000 steps per expert can take hours, and a model delivered late is
    a task lost."""
    demo = spec.demonstration()
    if demo is None or not experts:
        return
    from workers.mdrl.review import attach_review, review_experts

    deadline = None if seconds is None else time.monotonic() + seconds
    try:
        review = review_experts([(ref, str(experts[ref])) for ref in demo.experts], spec.env,
                                deadline=deadline)
        attach_review(model, review)
    except Exception as exc:  # noqa: BLE001 - any failure: deliver without the evidence
        log.warning("%s: no expert review in the card: %s: %s", model, type(exc).__name__, exc)


def warm_up() -> None:
    """Pay one-off costs before the first offer, so an accepted job starts training at once:
    the first ``torch.optim`` optimiser imports torch._dynamo (~2.5 s here), and the first
    rollout/update/evaluation import and initialise the rest of the core. One tiny update of a
    4x4 single-agent run, written nowhere."""
    from workers.mdrl.observations import ObservationSpec
    from workers.mdrl.ppo import PPOConfig
    from workers.mdrl.spec import EnvSpec

    run = RunConfig(
        seed=0,
        total_steps=8,
        eval_every=0,
        eval_episodes=2,
        checkpoint_every=0,
        tensorboard=False,
        progress=False,
    )
    trainer = JobTrainer(
        EnvSpec(rows=4, cols=4, agents=1),
        ObservationSpec(kind="odmtl", window=3),
        PPOConfig(num_envs=2, horizon=8, update_epochs=1, num_minibatches=1),
        run,
    )
    trainer.train()
