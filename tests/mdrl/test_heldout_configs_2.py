"""Held-out configurations of 2026-12-05: a spec the task-spec parser accepted and the trainer
then refused (now refused by the parser, naming the field, so the gateway does not take and
escrow a task no worker can train; a worker offered one from a direct write declines it,
tests/platform/test_heldout_worker_5.py), and CMTL's cost the resource model left out."""

import pytest

from workers.mdrl.observations import ObservationSpec, make_observer
from workers.mdrl.trainingspec import SpecError, TrainingSpec

CMTL_9_AGENTS = {"env": {"rows": 7, "cols": 8, "agents": 9}, "observation": {"kind": "cmtl"},
                 "budget": {"steps": 256}}


def test_the_trainer_refuses_cmtl_with_nine_agents() -> None:
    """What the spec below asks for: 5**9 joint actions, over MAX_JOINT_ACTIONS."""
    spec = TrainingSpec.from_dict({**CMTL_9_AGENTS, "observation": {"kind": "dmtl"}})
    with pytest.raises(ValueError, match="joint actions"):
        make_observer(spec.env, ObservationSpec(kind="cmtl"))


def test_the_spec_parser_refuses_cmtl_with_more_joint_actions_than_the_trainer_builds() -> None:
    with pytest.raises(SpecError, match="joint actions") as info:
        TrainingSpec.from_dict(CMTL_9_AGENTS)
    assert info.value.args[0].startswith(("observation.kind", "env.agents"))


def test_the_resource_model_charges_cmtl_its_joint_actions() -> None:
    """CMTL's passes over all A**N joint actions of each env at each step (mask, where,
    log_softmax, argmax: ~20 ns each here) were charged as its head's matmul only, so 5**8
    joint actions evaluated ~15x slower than estimated and a worker accepted deadlines its
    final evaluation could not hold (the measured figures: ``benchmarks/resource_estimate.py``,
    its CMTL row). Now update and evaluation estimates include JOINT_ACTION_S per joint
    action per step; DMTL's, with the same team, are unchanged by it."""
    from workers.mdrl import resources

    def both(kind: str) -> TrainingSpec:
        return TrainingSpec.from_dict({
            "env": {"rows": 3, "cols": 6, "agents": 8, "max_steps": 10},
            "observation": {"kind": kind}, "budget": {"steps": 16},
            "algorithm": {"ppo": {"num_envs": 4, "horizon": 4, "update_epochs": 1}},
        })

    cmtl, dmtl = both("cmtl"), both("dmtl")
    joint = resources.JOINT_ACTION_S * 5**8
    assert resources.joint_action_seconds(cmtl) == pytest.approx(joint)
    assert resources.joint_action_seconds(dmtl) == 0.0
    assert resources.final_evaluation_seconds(cmtl) >= 100 * 10 * joint
    assert resources.update_seconds(cmtl) >= cmtl.ppo.batch_steps * (1 + 3) * joint
    assert resources.worker_hours(cmtl) * 3600 >= (resources.update_seconds(cmtl)
                                                   + resources.final_evaluation_seconds(cmtl))
