"""Training runs: reproducibility, checkpoint/resume, model files, and that learning happens."""

import csv
import dataclasses
import json
import pickle

import numpy as np
import pytest
import torch
import typer
from safetensors.torch import load_file
from scipy import stats
from typer.testing import CliRunner

from workers.mdrl.checkpoint import load_checkpoint
from workers.mdrl.commands.train import train
from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.evaluate import evaluate
from workers.mdrl.modelio import load_model
from workers.mdrl.observations import ObservationSpec
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.presets import PRESETS, get_preset, load_config
from workers.mdrl.spec import EnvSpec
from workers.mdrl.train import METRIC_COLUMNS, TIMING_COLUMNS, RunConfig, Trainer

SMALL_ENV = EnvSpec(rows=6, cols=6, agents=2)
SMALL_PPO = PPOConfig(horizon=192, num_envs=16, update_epochs=2, num_minibatches=2,
                      learning_rate=1e-3, reward_scale=0.1)  # T = 12 steps per update


def small_run(seed=0, updates=3, **changes):
    defaults = dict(seed=seed, total_steps=updates * SMALL_PPO.batch_steps, eval_every=2,
                    eval_episodes=20, checkpoint_every=0, progress=False, tensorboard=False)
    return RunConfig(**{**defaults, **changes})


def read_metrics(path, timing=False):
    with open(path / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    if not timing:
        for r in rows:
            for c in TIMING_COLUMNS:
                del r[c]
    return rows


@pytest.mark.parametrize("kind", ["odmtl", "dmtl", "cmtl"])
def test_same_seed_same_metrics_and_another_seed_differs(tmp_path, kind):
    obs = ObservationSpec(kind=kind)
    runs = {}
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        Trainer(SMALL_ENV, obs, SMALL_PPO, small_run(seed=seed), out=tmp_path / name).train()
        runs[name] = read_metrics(tmp_path / name)
    assert len(runs["a"]) == 3
    assert list(runs["a"][0]) == [c for c in METRIC_COLUMNS if c not in TIMING_COLUMNS]
    assert runs["a"] == runs["b"]
    assert runs["a"] != runs["c"]
    wa = load_file(str(tmp_path / "a" / "model" / "model.safetensors"))
    wb = load_file(str(tmp_path / "b" / "model" / "model.safetensors"))
    assert all(torch.equal(wa[k], wb[k]) for k in wa)


def test_resume_continues_identically(tmp_path):
    obs = ObservationSpec(kind="odmtl")
    straight = Trainer(SMALL_ENV, obs, SMALL_PPO, small_run(updates=4), out=tmp_path / "straight")
    straight.train()
    split = Trainer(SMALL_ENV, obs, SMALL_PPO, small_run(updates=2), out=tmp_path / "split")
    split.train()  # stops after 2 updates, mid-episode in most envs, and checkpoints
    assert (split.env.t > 0).any()
    resumed = Trainer.resume(tmp_path / "split",
                             run_overrides={"total_steps": 4 * SMALL_PPO.batch_steps})
    assert resumed.update_idx == 2 and resumed.global_step == 2 * SMALL_PPO.batch_steps
    resumed.train()
    assert read_metrics(tmp_path / "straight") == read_metrics(tmp_path / "split")
    for k, v in straight.agent.state_dict().items():
        assert torch.equal(v, resumed.agent.state_dict()[k]), k
    np.testing.assert_array_equal(straight.env.pos, resumed.env.pos)
    np.testing.assert_array_equal(straight.env.readings, resumed.env.readings)


@pytest.mark.parametrize("kind", ["odmtl", "cmtl"])
@pytest.mark.parametrize("budget", [5, 17, 192 + 1, 2 * 192 + 45])
def test_a_step_budget_is_met_exactly(tmp_path, kind, budget):
    # SMALL_PPO collects 192 env steps per update (T = 12 x B = 16): none of these is a multiple
    assert budget % SMALL_PPO.batch_steps
    run = small_run(total_steps=budget, eval_every=0, checkpoint_every=1)
    trainer = Trainer(SMALL_ENV, ObservationSpec(kind=kind), SMALL_PPO, run, out=tmp_path)
    row = trainer.train()
    assert row["global_step"] == trainer.global_step == budget
    steps = [int(r["global_step"]) for r in read_metrics(tmp_path)]
    full = [SMALL_PPO.batch_steps * (i + 1) for i in range(budget // SMALL_PPO.batch_steps)]
    assert steps == full + [budget]
    assert trainer.env.active.all()  # the frozen envs of the last step are live again
    if budget < SMALL_PPO.num_envs:  # one time step in which only the first `budget` envs act
        assert (trainer.env.t[:budget] == 1).all() and (trainer.env.t[budget:] == 0).all()


def test_resume_after_a_short_last_rollout_continues_identically(tmp_path):
    obs = ObservationSpec(kind="odmtl")
    budget = 3 * SMALL_PPO.batch_steps + 70
    straight = Trainer(SMALL_ENV, obs, SMALL_PPO, small_run(total_steps=budget),
                       out=tmp_path / "straight")
    straight.train()
    split = Trainer(SMALL_ENV, obs, SMALL_PPO, small_run(total_steps=SMALL_PPO.batch_steps + 50),
                    out=tmp_path / "split")
    split.train()  # update 2 is short: 50 steps, 4 envs frozen in its last time step
    assert split.global_step == SMALL_PPO.batch_steps + 50
    resumed = Trainer.resume(tmp_path / "split", run_overrides={"total_steps": budget})
    resumed.train()
    assert resumed.global_step == straight.global_step == budget
    # not the same run as the straight one (update 2 was short), but a deterministic one:
    again = Trainer(SMALL_ENV, obs, SMALL_PPO, small_run(total_steps=SMALL_PPO.batch_steps + 50),
                    out=tmp_path / "again")
    again.train()
    Trainer.resume(tmp_path / "again", run_overrides={"total_steps": budget}).train()
    assert read_metrics(tmp_path / "split") == read_metrics(tmp_path / "again")
    assert [int(r["global_step"]) for r in read_metrics(tmp_path / "split")] == [
        192, 242, 434, 626, 646]


def test_checkpoint_round_trip_restores_every_part(tmp_path):
    t = Trainer(SMALL_ENV, ObservationSpec(kind="odmtl"), SMALL_PPO, small_run(updates=1),
                out=tmp_path / "run")
    t.train()
    tensors, env_arrays, meta = load_checkpoint(tmp_path / "run" / "checkpoint")
    json.dumps(meta)  # all of it is plain JSON
    assert meta["counters"]["update"] == 1
    assert "layout_rng" in meta["env_state"]["state_dict"]
    fresh = Trainer.resume(tmp_path / "run")
    for k, v in t.agent.state_dict().items():
        assert torch.equal(v, fresh.agent.state_dict()[k])
    sa, sb = t.optimizer.state_dict()["state"], fresh.optimizer.state_dict()["state"]
    assert sorted(sa) == sorted(sb) and len(sa) == len(list(t.agent.parameters()))
    for key in sa:
        p, q = sa[key], sb[key]
        assert torch.equal(p["exp_avg"], q["exp_avg"])
        assert torch.equal(p["exp_avg_sq"], q["exp_avg_sq"])
        assert torch.equal(torch.as_tensor(p["step"]), torch.as_tensor(q["step"]))
    assert torch.equal(t.generator.get_state(), fresh.generator.get_state())
    a, b = t.env.state_dict(), fresh.env.state_dict()
    for k in a[0]:
        np.testing.assert_array_equal(a[0][k], b[0][k])
    assert a[1] == b[1]
    # the restored env continues with the same random draws
    acts = np.zeros((SMALL_PPO.num_envs, SMALL_ENV.agents), dtype=np.int64)
    acts[:] = np.argmax(t.env.action_mask()[..., 1:], axis=-1) + 1  # a valid move per agent
    ra, rb = t.env.step(acts), fresh.env.step(acts)
    np.testing.assert_array_equal(ra.reward, rb.reward)
    np.testing.assert_array_equal(t.env.readings, fresh.env.readings)
    assert not any(p.suffix in (".pt", ".pth", ".pkl") for p in (tmp_path / "run").rglob("*"))


def test_model_files_load_without_pickle_and_act_like_the_trainer(tmp_path, monkeypatch):
    t = Trainer(SMALL_ENV, ObservationSpec(kind="odmtl"), SMALL_PPO, small_run(updates=2),
                out=tmp_path / "run")
    t.train()
    model_dir = tmp_path / "run" / "model"
    assert sorted(p.name for p in model_dir.iterdir()) == ["model.json", "model.safetensors"]

    def forbidden(*args, **kwargs):
        raise AssertionError("model loading must not unpickle")

    monkeypatch.setattr(pickle, "load", forbidden)
    monkeypatch.setattr(pickle, "loads", forbidden)
    monkeypatch.setattr(torch, "load", forbidden)
    policy = load_model(model_dir)
    card = policy.card
    assert card["env"] == SMALL_ENV.to_dict()
    assert card["observation"]["kind"] == "odmtl"
    assert card["architecture"]["actor_parameters"] == sum(
        p.numel() for p in t.agent.actor.parameters())
    assert card["action_space"]["per_agent_actions"] == 5
    assert card["training"]["ppo"]["horizon"] == SMALL_PPO.horizon
    assert card["metrics"]["eval_success"] == t.last_eval["eval_success"]
    env_a = TargetLocalizationEnv(SMALL_ENV, 32, seed=11, autoreset=False)
    env_b = TargetLocalizationEnv(SMALL_ENV, 32, seed=11, autoreset=False)
    trainer_policy = t.policy()
    for _ in range(10):
        a, b = policy.act(env_a), trainer_policy.act(env_b)
        np.testing.assert_array_equal(a, b)
        env_a.step(a)
        env_b.step(b)
    # and the loaded model scores exactly what the trainer's last evaluation scored
    rep = evaluate(policy, SMALL_ENV, t.run.eval_episodes, seed=t.run.eval_seed)
    assert rep.success_rate == t.last_eval["eval_success"]
    assert rep.time_mean == t.last_eval["eval_time"]


def test_cmtl_joint_actions_decode_to_valid_agent_actions(tmp_path):
    t = Trainer(SMALL_ENV, ObservationSpec(kind="cmtl"), SMALL_PPO, small_run(updates=1),
                out=None)
    assert t.head.policy_agents == 1 and t.head.policy_actions == 25
    t.collect()
    assert t.buffer.actions.shape == (SMALL_PPO.rollout_steps, SMALL_PPO.num_envs, 1)
    assert int(t.buffer.actions.max()) < 25
    # every stored joint action was valid under the stored joint mask
    chosen = t.buffer.masks.gather(-1, t.buffer.actions.unsqueeze(-1))
    assert bool(chosen.all())


def test_presets_and_config_files(tmp_path):
    assert {"odmtl-3a-10x10", "dmtl-3a-10x10", "cmtl-2a-10x10"} <= set(PRESETS)
    p = get_preset("odmtl-3a-10x10")
    assert p.env.agents == 3 and p.observation.kind == "odmtl"
    assert get_preset("odmtl-3a-10x10-t32").ppo == PPOConfig()  # Table 3.2 exactly
    (tmp_path / "c.toml").write_text('preset = "dmtl-2a-10x10"\n[ppo]\nlearning_rate = 0.002\n'
                                     '[env]\nrows = 8\n')
    c = load_config(tmp_path / "c.toml")
    assert (c.env.rows, c.env.agents, c.observation.kind, c.ppo.learning_rate) == (
        8, 2, "dmtl", 0.002)
    (tmp_path / "c.json").write_text(json.dumps({"env": {"agents": 1}, "ppo": {"horizon": 64}}))
    j = load_config(tmp_path / "c.json")
    assert j.env.agents == 1 and j.ppo.horizon == 64 and j.observation.kind == "odmtl"
    (tmp_path / "bad.json").write_text(json.dumps({"ppo": {"learning_rat": 1}}))
    with pytest.raises(ValueError, match="learning_rat"):
        load_config(tmp_path / "bad.json")
    with pytest.raises(ValueError, match="unknown preset"):
        get_preset("odmtl-99a")


def test_short_training_beats_the_random_policy(tmp_path):
    """~60k env steps of ODMTL, 1 agent, 6x6 (about 10-20 s on one core).

    Statistics: both policies play the same 200 seeded episodes. H0: the trained greedy policy
    localizes no faster than the random policy. One-sided Mann-Whitney U on the per-episode
    localization times; we require p < 1e-6, so a policy no better than random passes with
    probability < 1e-6. We also require the mean time to be at most half the random one
    (random walk: ~56 steps here, the oracle ~4).
    """
    from workers.mdrl.baselines import make_baseline

    env = EnvSpec(rows=6, cols=6, agents=1)
    ppo = PPOConfig(horizon=2048, num_envs=32, update_epochs=4, num_minibatches=4,
                    learning_rate=1e-3, reward_scale=0.1)
    run = RunConfig(seed=0, total_steps=60_000, eval_every=0, eval_episodes=200,
                    progress=False, tensorboard=False)
    trainer = Trainer(env, ObservationSpec(kind="odmtl"), ppo, run, out=tmp_path / "run")
    trainer.train()
    trained = evaluate(load_model(tmp_path / "run" / "model"), env, 200, seed=7)
    random = evaluate(make_baseline("random", seed=0), env, 200, seed=7)
    test = stats.mannwhitneyu(trained.time, random.time, alternative="less")
    assert test.pvalue < 1e-6, (trained.summary, random.summary)
    assert trained.time_mean <= 0.5 * random.time_mean
    assert trained.success_rate >= random.success_rate


# ---------------------------------------------------------------- the `train` command

def make_app():
    app = typer.Typer()
    app.command()(train)
    app.command("noop")(lambda: None)  # keep `train` as a named sub-command
    return app


def test_train_command_writes_outputs_and_resumes(tmp_path):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text('preset = "odmtl-2a-10x10"\n[env]\nrows = 6\ncols = 6\n'
                   '[ppo]\nhorizon = 128\nnum_envs = 16\nupdate_epochs = 1\n'
                   '[run]\neval_episodes = 10\neval_every = 1\n')
    out = tmp_path / "run"
    runner = CliRunner()
    res = runner.invoke(make_app(), ["train", "--config", str(cfg), "--steps", "256",
                                     "--seed", "5", "--out", str(out), "--no-progress"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output.strip().splitlines()[-1])
    assert summary["env_steps"] == 256 and summary["updates"] == 2
    assert 0.0 <= summary["eval_success"] <= 1.0
    assert (out / "model" / "model.safetensors").is_file()
    assert (out / "checkpoint" / "state.json").is_file()
    assert list((out / "tb").glob("events.out.tfevents.*"))
    res = runner.invoke(make_app(), ["train", "--resume", str(out), "--steps", "384",
                                     "--no-progress"])
    assert res.exit_code == 0, res.output
    with open(out / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["update"]) for r in rows] == [1, 2, 3]
    assert [int(r["global_step"]) for r in rows] == [128, 256, 384]


def test_train_command_needs_a_budget(tmp_path):
    res = CliRunner().invoke(make_app(), ["train", "--out", str(tmp_path / "x")])
    assert res.exit_code != 0
    assert "budget" in res.output


def test_the_core_alone_names_an_expert_cid_it_cannot_fetch(tmp_path, monkeypatch):
    """The MDRL core trains from directories: a CID needs the platform CLI's fetcher
    (drlaas/cli.py sets MODEL_FETCHER), and without it the error says what to do."""
    import workers.mdrl.commands.train as command

    monkeypatch.setattr(command, "MODEL_FETCHER", None)
    cid = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
    res = CliRunner().invoke(make_app(), ["train", "--steps", "64", "--experts", f"oracle,{cid}",
                                          "--out", str(tmp_path / "run"), "--no-progress"])
    text = " ".join(res.output.replace("│", " ").split())
    assert res.exit_code == 2 and cid in text and "drlaas model pull" in text, res.output
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(("args", "named"), [
    (["--preset", "odmtl-3a-10x1O"], ["--preset", "unknown preset 'odmtl-3a-10x1O'"]),
    (["--config", "{dir}/missing.toml"], ["--config", "not found"]),
    (["--config", "{dir}/typo.toml"], ["--config", "rows must be an integer"]),
    (["--config", "{dir}/nonsense.toml"], ["--config", "must be a table"]),
])
def test_train_command_names_a_bad_preset_or_config_without_a_traceback(tmp_path, args, named):
    (tmp_path / "typo.toml").write_text('[env]\nrows = "ten"\n')
    (tmp_path / "nonsense.toml").write_text("env = 3\n")
    args = [a.format(dir=tmp_path) for a in args]
    res = CliRunner().invoke(make_app(), ["train", *args, "--steps", "64",
                                          "--out", str(tmp_path / "run"), "--no-progress"])
    assert res.exit_code == 2, res.output  # a usage error, not a crash
    assert res.exception is None or isinstance(res.exception, SystemExit)
    flat = " ".join(res.output.replace("│", " ").split())
    assert all(n in flat for n in named), flat
    assert not (tmp_path / "run").exists()


def test_train_command_prints_json_with_null_for_figures_without_episodes(tmp_path):
    """A run shorter than any episode has no training success: null, not NaN (not JSON)."""
    cfg = tmp_path / "tiny.toml"
    cfg.write_text('preset = "odmtl-2a-10x10"\n'
                   '[ppo]\nhorizon = 2\nnum_envs = 2\nupdate_epochs = 1\n'
                   '[run]\neval_episodes = 2\neval_every = 1\n')
    res = CliRunner().invoke(make_app(), ["train", "--config", str(cfg), "--steps", "2",
                                          "--out", str(tmp_path / "run"), "--no-progress"])
    assert res.exit_code == 0, res.output
    line = res.output.strip().splitlines()[-1]
    summary = json.loads(line, parse_constant=lambda c: pytest.fail(f"{c} in {line}"))
    assert summary["train_success"] is None


def test_init_from_starts_from_a_models_weights_and_the_card_names_it(tmp_path):
    obs = ObservationSpec(kind="odmtl")
    first = Trainer(SMALL_ENV, obs, SMALL_PPO, small_run(updates=2), out=tmp_path / "first")
    first.train()
    start = tmp_path / "first" / "model"
    # another task (sparse reward, another seed), same observation and team: fine-tuning fits
    task = SMALL_ENV.replace(reward="sparse")
    tuned = Trainer(task, obs, SMALL_PPO, small_run(seed=9, updates=2, checkpoint_every=1,
                                                    init_from=str(start)), out=tmp_path / "tuned")
    fresh = Trainer(task, obs, SMALL_PPO, small_run(seed=9, updates=2), out=tmp_path / "fresh")
    for k, v in first.agent.state_dict().items():
        assert torch.equal(v, tuned.agent.state_dict()[k]), k
    assert any(not torch.equal(v, fresh.agent.state_dict()[k])
               for k, v in first.agent.state_dict().items())
    tuned.run = dataclasses.replace(tuned.run, total_steps=SMALL_PPO.batch_steps)
    tuned.train()  # one update, checkpointed
    # a resumed run continues from its checkpoint: the start model may be gone by then
    for f in start.iterdir():
        f.unlink()
    start.rmdir()
    resumed = Trainer.resume(tmp_path / "tuned",
                             run_overrides={"total_steps": 2 * SMALL_PPO.batch_steps})
    resumed.train()
    card = json.loads((tmp_path / "tuned" / "model" / "model.json").read_text())
    init = card["training"]["init_from"]
    assert init["ref"] == str(start) and len(init["weights_sha256"]) == 64
    assert init["env_steps"] == 2 * SMALL_PPO.batch_steps
    assert card["training"]["run"]["init_from"] == str(start)
    assert fresh.init_info is None


@pytest.mark.parametrize(("run_env", "run_obs", "named"), [
    (SMALL_ENV, ObservationSpec(kind="odmtl", window=5), "['window']"),
    (SMALL_ENV, ObservationSpec(kind="dmtl"), "'kind'"),
    (SMALL_ENV.replace(agents=3), ObservationSpec(kind="odmtl"), "this run has 3"),
    (SMALL_ENV.replace(walls=(1, 1)), ObservationSpec(kind="odmtl"), "inputs of shape"),
])
def test_init_from_refuses_a_model_that_does_not_fit(tmp_path, run_env, run_obs, named):
    first = Trainer(SMALL_ENV, ObservationSpec(kind="odmtl"), SMALL_PPO, small_run(updates=1),
                    out=tmp_path / "first")
    first.train()
    with pytest.raises(ValueError, match="init_from") as err:
        Trainer(run_env, run_obs, SMALL_PPO, small_run(init_from=str(tmp_path / "first" /
                                                                     "model")))
    assert named in str(err.value)


def test_train_command_init_from_a_model_that_does_not_fit_is_a_usage_error(tmp_path):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text('preset = "odmtl-2a-10x10"\n[env]\nrows = 6\ncols = 6\n'
                   '[ppo]\nhorizon = 64\nnum_envs = 8\nupdate_epochs = 1\n'
                   '[run]\neval_episodes = 4\n')
    runner = CliRunner()
    res = runner.invoke(make_app(), ["train", "--config", str(cfg), "--steps", "64",
                                     "--out", str(tmp_path / "a"), "--no-progress"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(make_app(), ["train", "--preset", "odmtl-3a-10x10", "--steps", "64",
                                     "--init-from", str(tmp_path / "a" / "model"),
                                     "--out", str(tmp_path / "b"), "--no-progress"])
    assert res.exit_code == 2, res.output
    flat = " ".join(res.output.replace("│", " ").split())
    assert "--init-from" in flat and "2 agent(s)" in flat, flat
    res = runner.invoke(make_app(), ["train", "--config", str(cfg), "--steps", "128",
                                     "--init-from", str(tmp_path / "a" / "model"),
                                     "--out", str(tmp_path / "c"), "--no-progress"])
    assert res.exit_code == 0, res.output
    card = json.loads((tmp_path / "c" / "model" / "model.json").read_text())
    assert card["training"]["init_from"]["env_steps"] == 64


def test_a_finished_run_resumed_keeps_its_card(tmp_path):
    """A kill after the last checkpoint and before (or while) the model was written: the
    resumed run has no update left to run, and its card lost every training figure but the
    evaluation (17 of 20 metrics; train_success null)."""
    import json

    obs = ObservationSpec(kind="odmtl")
    done = Trainer(SMALL_ENV, obs, SMALL_PPO, small_run(updates=2), out=tmp_path)
    final = done.train()
    card = json.loads((tmp_path / "model" / "model.json").read_text())
    again = Trainer.resume(tmp_path)
    assert again.update_idx == 2
    row = again.train()
    assert row == final or json.dumps(row, sort_keys=True) == json.dumps(final, sort_keys=True)
    resumed_card = json.loads((tmp_path / "model" / "model.json").read_text())
    assert resumed_card["metrics"] == card["metrics"]
    assert resumed_card["metrics"]["success"] == final["success"]


def test_a_run_killed_between_the_checkpoint_renames_resumes(tmp_path):
    """atomic_dir moves the last checkpoint to checkpoint.old before renaming the new one in:
    a kill between the two left only checkpoint.old, and --resume said "cannot resume"."""
    obs = ObservationSpec(kind="odmtl")
    Trainer(SMALL_ENV, obs, SMALL_PPO, small_run(updates=2), out=tmp_path).train()
    (tmp_path / "checkpoint").rename(tmp_path / "checkpoint.old")
    resumed = Trainer.resume(tmp_path, run_overrides={"total_steps": 3 * SMALL_PPO.batch_steps})
    assert resumed.update_idx == 2
    assert (tmp_path / "checkpoint" / "state.json").is_file()
    assert not (tmp_path / "checkpoint.old").exists()
    resumed.train()
    assert resumed.update_idx == 3
