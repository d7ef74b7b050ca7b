"""The resource model counts the fixed cost of a PPO update (resources.update_overhead_seconds):
FLOPs alone made an update of one env step ~0.01 ms where it takes ~7 ms on this machine."""

from __future__ import annotations

import pytest

from workers.mdrl import resources
from workers.mdrl.resources import estimate, update_seconds, worker_hours
from workers.mdrl.trainingspec import TrainingSpec

TINY = {"num_envs": 1, "horizon": 1, "update_epochs": 1, "num_minibatches": 1}


def spec(ppo: dict, budget: dict | None = None) -> TrainingSpec:
    return TrainingSpec.from_dict({
        "env": {"rows": 4, "cols": 4, "agents": 1}, "observation": {"kind": "odmtl"},
        "algorithm": {"ppo": ppo}, "budget": budget or {"steps": 1_000_000},
    })


def flops_only(s: TrainingSpec) -> float:
    return resources.flops_per_step(s) * s.ppo.batch_steps / resources.reference_flops_per_s()


def test_an_update_of_one_env_step_costs_milliseconds_not_microseconds() -> None:
    s = spec(TINY)
    assert s.ppo.batch_steps == 1
    # a few ms: one rollout step, one optimizer step and the update's bookkeeping
    assert update_seconds(s) >= 0.005
    assert update_seconds(s) > 100 * flops_only(s)


def test_the_overhead_grows_with_rollout_steps_and_optimizer_steps() -> None:
    base = update_seconds(spec(TINY))
    longer = update_seconds(spec(TINY | {"horizon": 64}))  # 64 sequential steps of one env
    assert longer - base >= 63 * resources.ROLLOUT_STEP_S
    more = update_seconds(spec(TINY | {"horizon": 16, "update_epochs": 4, "num_minibatches": 16}))
    fewer = update_seconds(spec(TINY | {"horizon": 16}))
    assert more - fewer >= 63 * resources.OPTIMIZER_STEP_S


def test_worker_hours_and_a_time_budget_count_the_updates() -> None:
    """A million updates of one env step are hours of work, not seconds; a week's budget
    of them is as many env steps as that many updates, not what FLOPs alone allow."""
    s = spec(TINY)
    assert worker_hours(s) >= 1_000_000 * 0.005 / 3600  # over an hour (FLOPs: ~4 s)
    assert worker_hours(s) >= 1_000_000 * update_seconds(s) / 3600 * 0.99
    week = estimate(spec(TINY, {"minutes": 7 * 24 * 60})).env_steps
    assert week <= 7 * 24 * 3600 / 0.005 and week <= 7 * 24 * 3600 / update_seconds(s)


def test_the_reference_preset_is_not_charged_its_overhead_twice() -> None:
    """The reference rate (7,000 env steps/s) was measured with the overhead in it: an hour
    of the reference preset's steps is still an hour."""
    ref = TrainingSpec.from_dict({
        "env": {"rows": 10, "cols": 10, "agents": 3},
        "observation": resources.REFERENCE_OBSERVATION,
        "algorithm": {"preset": resources.REFERENCE_PRESET},
        "budget": {"steps": resources.REFERENCE_STEPS_PER_S * 3600},
    })
    assert update_seconds(ref) == pytest.approx(
        ref.ppo.batch_steps / resources.REFERENCE_STEPS_PER_S)
    assert worker_hours(ref) == pytest.approx(1.0, rel=1e-3)


def test_the_final_evaluation_counts_a_dispatch_per_time_step() -> None:
    """The final evaluation steps its episodes together (``evaluate``): each time step pays an
    observe, an actor pass and an env step of Python and torch dispatch, which the FLOPs of a
    4 x 4 grid do not show: a spec of 10,000-step episodes on it was estimated 1.6 s of final
    evaluation, without the ~10 s its dispatches take (``ROLLOUT_STEP_S`` each, measured by
    ``benchmarks/update_overhead.py``); a worker then accepted deadlines it could not hold."""
    long = TrainingSpec.from_dict({
        "env": {"rows": 4, "cols": 4, "agents": 1, "max_steps": 10_000},
        "observation": {"kind": "odmtl"}, "budget": {"steps": 1_000},
    })
    flops_s = resources.final_evaluation_flops(long) / resources.reference_flops_per_s()
    assert resources.final_evaluation_seconds(long) >= flops_s + 10_000 * resources.ROLLOUT_STEP_S
    assert resources.final_evaluation_seconds(long) > 5 * flops_s
    # a job's hours and a time budget's steps keep the same evaluation time
    assert worker_hours(long) * 3600 >= resources.final_evaluation_seconds(long)


def test_the_final_evaluation_dispatches_as_evaluate_groups_its_chunks() -> None:
    """At 30 x 30 the 100 episodes are chunks of 24 (the baselines' tables), stepped four
    chunks at a time: two groups, each ``max_steps`` dispatches; at 10 x 10 one."""
    def dispatch_s(rows: int) -> float:
        s = TrainingSpec.from_dict({
            "env": {"rows": rows, "cols": rows, "agents": 1, "max_steps": 1_000},
            "observation": {"kind": "odmtl"}, "budget": {"steps": 1_000},
        })
        return (resources.final_evaluation_seconds(s)
                - resources.final_evaluation_flops(s) / resources.reference_flops_per_s())

    assert dispatch_s(10) == pytest.approx(1_000 * resources.ROLLOUT_STEP_S)
    assert dispatch_s(30) == pytest.approx(2 * 1_000 * resources.ROLLOUT_STEP_S)


def test_a_jobs_logs_are_bounded_by_its_budget_and_deadline() -> None:
    """Each update appends a metrics row and a progress line: the updates a job may run are
    its step budget's, and no more than its time (budget or deadline) holds at a quarter of
    the estimated update time; a week of one-step updates is tens of GB of logs."""
    steps = spec(TINY | {"horizon": 8}, {"steps": 8_000})
    assert resources.max_updates(steps) == 1_000
    assert resources.log_bytes(steps) == 1_000 * resources.LOG_BYTES_PER_UPDATE
    assert resources.max_updates(steps, seconds=0.0) == 1  # a deadline now: the one it starts
    week = spec(TINY, {"minutes": 7 * 24 * 60})
    fastest = update_seconds(week) * resources.FASTEST_UPDATE_FRACTION
    assert resources.max_updates(week) == int(7 * 24 * 3600 / fastest) + 1
    assert resources.log_bytes(week) > 10 * 2**30
    hour = 3600.0  # the deadline, sooner than the budget, bounds it
    assert resources.max_updates(week, seconds=hour) == int(hour / fastest) + 1
