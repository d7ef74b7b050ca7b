"""Model selection (RunConfig.keep_best): the best evaluated policy is kept, as files and in
memory, survives a resume, and is the one its card's figures describe."""

import csv
import json
import math

import pytest
import torch
from safetensors.torch import load_file
from typer.testing import CliRunner

from tests.mdrl.test_train import make_app
from workers.mdrl.evaluate import evaluate
from workers.mdrl.modelio import load_model
from workers.mdrl.observations import ObservationSpec
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.spec import EnvSpec
from workers.mdrl.train import KEEP_BEST, RunConfig, Trainer

ENV = EnvSpec(rows=6, cols=6, agents=2)
PPO = PPOConfig(horizon=96, num_envs=8, update_epochs=2, num_minibatches=2,
                learning_rate=3e-3, reward_scale=0.1)  # 96 env steps per update
OBS = ObservationSpec(kind="odmtl")
UPDATES = 8


def run_config(updates=UPDATES, **changes):
    d = dict(seed=1, total_steps=updates * PPO.batch_steps, eval_every=1, eval_episodes=16,
             checkpoint_every=1, progress=False, tensorboard=False, keep_best="time")
    return RunConfig(**{**d, **changes})


def evaluations(out):
    with open(out / "metrics.csv", newline="") as f:
        return [{"update": int(r["update"]), "eval_time": float(r["eval_time"]),
                 "eval_cost": float(r["eval_cost"])} for r in csv.DictReader(f) if r["eval_time"]]


def expected_best(rows, by):
    first, second = KEEP_BEST[by]
    return min(rows, key=lambda r: (r[first], r[second], r["update"]))


@pytest.mark.parametrize("by", ["time", "cost"])
def test_the_kept_policy_is_the_best_evaluation_and_its_files_reproduce_it(tmp_path, by):
    trainer = Trainer(ENV, OBS, PPO, run_config(keep_best=by), out=tmp_path)
    trainer.train()
    rows = evaluations(tmp_path)
    assert len(rows) == UPDATES
    want = expected_best(rows, by)
    assert trainer.best["by"] == by and trainer.best["update"] == want["update"]
    assert trainer.best["eval_time"] == pytest.approx(want["eval_time"])
    # the run moved on from the best (else the test could not tell best from last)
    assert want["update"] != UPDATES
    final = load_file(str(tmp_path / "model" / "model.safetensors"))
    best = load_file(str(tmp_path / "best" / "model.safetensors"))
    assert any(not torch.equal(final[k], best[k]) for k in final)
    # the best model file, loaded like any model, does on the evaluation episodes what the card
    # and the metrics say, and so does the in-memory best policy
    card = json.loads((tmp_path / "best" / "model.json").read_text())
    assert card["training"]["selected"]["update"] == want["update"]
    assert card["training"]["selected"]["eval_seed"] == trainer.run.eval_seed
    assert card["training"]["env_steps"] == want["update"] * PPO.batch_steps  # when it was kept
    assert card["metrics"]["eval_time"] == pytest.approx(want["eval_time"])
    for policy in (load_model(tmp_path / "best"), trainer.policy(best=True)):
        report = evaluate(policy, ENV, 16, seed=trainer.run.eval_seed)
        assert report.time_mean == pytest.approx(want["eval_time"])
        assert report.cost_mean == pytest.approx(want["eval_cost"])
    # the final policy is untouched by the selection
    last = evaluate(trainer.policy(), ENV, 16, seed=trainer.run.eval_seed)
    assert last.time_mean == pytest.approx(rows[-1]["eval_time"])


def test_a_resumed_run_keeps_the_same_best_as_one_never_interrupted(tmp_path):
    straight = Trainer(ENV, OBS, PPO, run_config(), out=tmp_path / "straight")
    straight.train()
    split = Trainer(ENV, OBS, PPO, run_config(updates=UPDATES // 2), out=tmp_path / "split")
    split.train()
    resumed = Trainer.resume(tmp_path / "split",
                             run_overrides={"total_steps": UPDATES * PPO.batch_steps})
    assert resumed.best == split.best  # figures and weights come back from the checkpoint
    resumed.train()

    def chosen(best: dict) -> dict:  # wall_time_s is the clock's
        return {k: v for k, v in best.items() if k != "wall_time_s"}

    assert chosen(resumed.best) == chosen(straight.best)
    a = load_file(str(tmp_path / "straight" / "best" / "model.safetensors"))
    b = load_file(str(tmp_path / "split" / "best" / "model.safetensors"))
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_resuming_with_another_rule_chooses_anew(tmp_path):
    Trainer(ENV, OBS, PPO, run_config(updates=3), out=tmp_path).train()
    resumed = Trainer.resume(tmp_path, run_overrides={"total_steps": 4 * PPO.batch_steps,
                                                      "keep_best": "cost"})
    assert resumed.best is None
    resumed.train()
    assert resumed.best["by"] == "cost" and resumed.best["update"] == 4


def test_without_the_rule_nothing_is_kept(tmp_path):
    trainer = Trainer(ENV, OBS, PPO, run_config(updates=2, keep_best=None), out=tmp_path)
    trainer.train()
    assert trainer.best is None and not (tmp_path / "best").exists()
    with pytest.raises(ValueError, match="no best policy"):
        trainer.policy(best=True)


def test_an_unknown_rule_is_refused_by_name():
    with pytest.raises(ValueError, match="keep_best.*'speed'"):
        RunConfig(keep_best="speed")
    for bad in (3, ["time"]):
        with pytest.raises(ValueError, match="keep_best"):
            RunConfig.from_dict({"keep_best": bad})


def test_a_failed_evaluation_never_beats_a_real_one(tmp_path):
    trainer = Trainer(ENV, OBS, PPO, run_config(updates=1), out=None)
    assert trainer.keep_if_best({"eval_success": 1.0, "eval_time": 9.0, "eval_cost": 12.0})
    assert not trainer.keep_if_best({"eval_success": 0.0, "eval_time": math.nan,
                                     "eval_cost": math.nan})
    assert not trainer.keep_if_best({"eval_success": 1.0, "eval_time": 9.0, "eval_cost": 12.0})
    assert trainer.keep_if_best({"eval_success": 1.0, "eval_time": 9.0, "eval_cost": 11.0})
    assert trainer.best["eval_cost"] == 11.0


def test_train_command_keep_best(tmp_path):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text('preset = "odmtl-2a-10x10"\n[env]\nrows = 6\ncols = 6\n'
                   '[ppo]\nhorizon = 64\nnum_envs = 8\nupdate_epochs = 1\n'
                   '[run]\neval_episodes = 8\neval_every = 1\n')
    runner = CliRunner()
    base = ["train", "--config", str(cfg), "--steps", "192", "--no-progress", "--no-tensorboard"]
    res = runner.invoke(make_app(), [*base, "--out", str(tmp_path / "bad"), "--keep-best", "fast"])
    assert res.exit_code == 2 and "--keep-best" in res.output and "'fast'" in res.output
    assert not (tmp_path / "bad").exists()
    res = runner.invoke(make_app(), [*base, "--out", str(tmp_path / "run"), "--keep-best", "time"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output.strip().splitlines()[-1])
    rows = evaluations(tmp_path / "run")
    want = expected_best(rows, "time")
    assert summary["best"] == str(tmp_path / "run" / "best")
    assert summary["best_update"] == want["update"]
    assert summary["best_eval_time"] == pytest.approx(want["eval_time"])
    assert (tmp_path / "run" / "best" / "model.json").is_file()
