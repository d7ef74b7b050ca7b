"""The generalist trainer: one actor-critic shared by set-ups of other grids and team sizes."""

from __future__ import annotations

import dataclasses

import torch

from workers.mdrl.generalist import GeneralistTrainer, training_setups
from workers.mdrl.modelio import load_model
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.train import RunConfig

PPO = PPOConfig(num_envs=8, horizon=64, update_epochs=1, num_minibatches=2)


def test_setups_vary_grid_and_team_within_bounds_and_are_seeded():
    setups = training_setups(seed=3, count=20)
    assert setups == training_setups(seed=3, count=20)
    assert all(8 <= s.rows <= 16 and 8 <= s.cols <= 16 and 1 <= s.agents <= 5 for s in setups)
    assert len({(s.rows, s.cols) for s in setups}) > 5 and len({s.agents for s in setups}) > 2
    assert all(s.cell_size_m == (100.0, 100.0) for s in setups)


def test_one_network_trains_on_every_setup_and_resumes(tmp_path):
    pool = training_setups(seed=0, count=40)
    setups = [next(s for s in pool if s.agents == 1), next(s for s in pool if s.agents == 4)]
    # a lone agent and a team of four on other grids share the actor
    run = RunConfig(seed=0, total_steps=4 * 64, tensorboard=False, progress=False)
    trainer = GeneralistTrainer(PPO, run, tmp_path, setups=setups)
    assert all(t.agent is trainer.agent for t in trainer.trainers)
    before = [p.detach().clone() for p in trainer.agent.parameters()]
    trainer.train()
    assert trainer.global_step == 4 * 64 and trainer.update_idx == 4
    rows = (tmp_path / "metrics.csv").read_text().splitlines()[1:]
    assert [r.split(",")[3] for r in rows] == ["0", "1", "0", "1"]  # set-ups in turn
    assert any(not torch.equal(a, b) for a, b in zip(before, trainer.agent.parameters(),
                                                      strict=True))
    resumed = GeneralistTrainer.resume(tmp_path, {"total_steps": 6 * 64})
    for a, b in zip(trainer.agent.state_dict().values(), resumed.agent.state_dict().values(),
                    strict=True):
        assert torch.equal(a, b)
    assert resumed.global_step == trainer.global_step
    # the saved model runs on a set-up it never saw (another grid and team size)
    policy = load_model(tmp_path / "model")
    from workers.mdrl.commands.evaluate import model_policy_for
    from workers.mdrl.evaluate import evaluate

    spec = dataclasses.replace(policy.env_spec, rows=9, cols=13, area_m=(900.0, 1300.0),
                               agents=6, walls=(1, 3))
    report = evaluate(model_policy_for(tmp_path / "model", spec, policy.env_spec, policy), spec,
                      8, seed=1)
    assert report.episodes == 8
