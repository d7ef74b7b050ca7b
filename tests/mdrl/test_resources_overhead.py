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
