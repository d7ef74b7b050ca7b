"""Bad inputs to the MDRL core and its CLI (`drlaas train`, `drlaas eval`, `drlaas cae train`):
each is refused up front with a message naming the field (a usage error, exit code 2, no
traceback), before anything is allocated or written; a time budget ends like a step budget
(final evaluation and checkpoint); a diverged run stops without a model."""

import json
import math
import os
import shutil

import pytest
import typer
from safetensors.torch import load_file, save_file
from typer.testing import CliRunner

from workers.mdrl.cae import train_cae
from workers.mdrl.commands.cae import app as cae_app
from workers.mdrl.commands.evaluate import eval_command
from workers.mdrl.commands.train import train, usable_cpus
from workers.mdrl.experts import ExpertError, load_expert
from workers.mdrl.modelio import load_model
from workers.mdrl.observations import MAX_JOINT_ACTIONS, ObservationSpec, make_observer
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.presets import preset_from_dict
from workers.mdrl.spec import MAX_CELLS, EnvSpec
from workers.mdrl.train import RunConfig, Trainer, TrainingDiverged

TINY = {"preset": "odmtl-2a-10x10", "env": {"rows": 6, "cols": 6},
        "ppo": {"horizon": 64, "num_envs": 8, "update_epochs": 1},
        "run": {"eval_episodes": 4, "eval_every": 0}}
"""A config that trains in well under a second per update (64 env steps per update)."""
QUIET = ["--no-progress", "--no-tensorboard"]


def make_app():
    app = typer.Typer()
    app.command()(train)
    app.command("eval")(eval_command)
    app.add_typer(cae_app, name="cae")
    return app


def invoke(*args):
    return CliRunner().invoke(make_app(), [str(a) for a in args])


def flat(res) -> str:
    return " ".join(res.output.replace("│", " ").split())


def config(tmp_path, name="tiny", **sections):
    """A JSON config file: TINY with ``sections`` merged into its sections."""
    doc = json.loads(json.dumps(TINY))
    for key, changes in sections.items():
        doc[key] = {**doc.get(key, {}), **changes} if isinstance(changes, dict) else changes
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(doc))  # json writes NaN / Infinity tokens, as a user may
    return path


def assert_clean_exit(res, code):
    """Exit ``code`` by the CLI's own exit, no traceback."""
    assert res.exit_code == code, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    assert "Traceback" not in res.output


def assert_usage_error(res, *named):
    """Exit code 2 (a usage error), no traceback, and every ``named`` text in the message."""
    assert_clean_exit(res, 2)
    text = flat(res)
    assert all(n in text for n in named), text


# ---------------------------------------------------------------- 1. a time-only budget
def test_a_time_budget_ends_with_an_evaluation_and_a_checkpoint_and_resumes(tmp_path):
    out = tmp_path / "run"
    res = invoke("train", "--config", config(tmp_path), "--minutes", 0.002, "--out", out,
                 *QUIET, "--checkpoint-every", 0)
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output.strip().splitlines()[-1])
    assert "eval_success" in summary and summary["updates"] >= 1
    card = json.loads((out / "model" / "model.json").read_text())
    assert "eval_success" in card["metrics"]
    assert (out / "checkpoint" / "state.json").is_file()
    # a resumed run counts its prior time (a loaded machine may take seconds): that, plus 3 s
    prior_s = float((out / "metrics.csv").read_text().splitlines()[-1].split(",")[2])
    res = invoke("train", "--resume", out, "--minutes", (prior_s + 3) / 60, *QUIET)
    assert res.exit_code == 0, res.output
    assert json.loads(res.output.strip().splitlines()[-1])["updates"] > summary["updates"]


def test_trainer_time_budget_saves_the_last_update(tmp_path):
    preset = preset_from_dict(TINY)
    run = RunConfig(minutes=1e-4, eval_every=0, checkpoint_every=0, eval_episodes=2,
                    progress=False, tensorboard=False)
    trainer = Trainer(preset.env, preset.observation, preset.ppo, run, out=tmp_path)
    trainer.train()
    assert trainer.last_eval and trainer.update_idx >= 1
    resumed = Trainer.resume(tmp_path, run_overrides={"minutes": 1.0})
    assert resumed.update_idx == trainer.update_idx


def test_a_time_budget_leaves_room_for_the_final_evaluation(tmp_path, monkeypatch):
    """A worker trains to its task's deadline: the final evaluation must fit in the budget, not
    start when it is used up. On a fake clock (updates 10 s, evaluations 25 s, 100 s budget,
    an evaluation after every update) the run stops after update 2 (45 s, its evaluation ends
    at 70 s: a third update and its evaluation would end at 105 s); it used to run 4 updates
    and end at 140 s."""
    from types import SimpleNamespace

    import workers.mdrl.train as train_module

    preset = preset_from_dict(TINY)
    run = RunConfig(minutes=100 / 60, eval_every=1, checkpoint_every=0, eval_episodes=2,
                    progress=False, tensorboard=False)
    trainer = Trainer(preset.env, preset.observation, preset.ppo, run, out=tmp_path)
    now = [0.0]
    monkeypatch.setattr(train_module, "time", SimpleNamespace(perf_counter=lambda: now[0]))
    real_update, real_evaluate = trainer.update, trainer.evaluate

    def update():
        now[0] += 10.0
        return real_update()

    def evaluate():
        now[0] += 25.0
        return real_evaluate()

    trainer.update, trainer.evaluate = update, evaluate
    trainer.train()
    assert trainer.update_idx == 2 and trainer.elapsed == pytest.approx(70.0)
    assert (tmp_path / "model" / "model.json").is_file() and trainer.last_eval


# ---------------------------------------------------------------- 2. --resume --seed
def test_resume_refuses_a_new_seed(trained):
    before = (trained / "checkpoint" / "state.json").read_text()
    res = invoke("train", "--resume", trained, "--steps", 128, "--seed", 3, *QUIET)
    assert_usage_error(res, "--resume continues a run", "--seed")
    assert (trained / "checkpoint" / "state.json").read_text() == before


# ---------------------------------------------------------------- 3. the config's budget
def test_a_configs_budget_and_seed_are_used_unless_a_flag_overrides_them(tmp_path):
    cfg = config(tmp_path, run={"total_steps": 128, "seed": 7})
    res = invoke("train", "--config", cfg, "--out", tmp_path / "a", *QUIET)
    assert res.exit_code == 0, res.output
    assert json.loads(res.output.strip().splitlines()[-1])["env_steps"] == 128
    card = json.loads((tmp_path / "a" / "model" / "model.json").read_text())
    assert card["training"]["run"]["seed"] == 7
    res = invoke("train", "--config", cfg, "--minutes", 5, "--out", tmp_path / "b", *QUIET)
    assert res.exit_code == 0, res.output  # the config's steps still end it
    assert json.loads(res.output.strip().splitlines()[-1])["env_steps"] == 128
    res = invoke("train", "--config", cfg, "--steps", 64, "--seed", 2, "--out", tmp_path / "c",
                 *QUIET)
    assert json.loads(res.output.strip().splitlines()[-1])["env_steps"] == 64
    card = json.loads((tmp_path / "c" / "model" / "model.json").read_text())
    assert card["training"]["run"]["seed"] == 2


# ---------------------------------------------------------------- 4. non-finite values
@pytest.mark.parametrize("field", ["learning_rate", "reward_scale", "ent_coef", "vf_coef",
                                   "adam_eps", "gamma", "max_grad_norm", "target_kl"])
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_ppo_config_refuses_non_finite_values_by_name(field, value):
    with pytest.raises(ValueError, match=field):
        PPOConfig(**{field: value})


def test_a_diverging_run_stops_with_a_clear_error_and_no_model(tmp_path):
    preset = preset_from_dict(TINY)
    ppo = PPOConfig(**{**preset.ppo.to_dict(), "learning_rate": 1e30, "update_epochs": 2})
    run = RunConfig(total_steps=640, eval_every=0, checkpoint_every=0, eval_episodes=2,
                    progress=False, tensorboard=False)
    trainer = Trainer(preset.env, preset.observation, ppo, run, out=tmp_path / "run")
    with pytest.raises(TrainingDiverged, match="diverged.*learning_rate"):
        trainer.train()
    assert not (tmp_path / "run" / "model").exists()
    res = invoke("train", "--config", config(tmp_path, ppo={"learning_rate": 1e30,
                                                           "update_epochs": 2}),
                 "--steps", 640, "--out", tmp_path / "cli", *QUIET)
    assert res.exit_code == 1 and "training diverged" in flat(res), res.output
    assert "Traceback" not in res.output and not (tmp_path / "cli" / "model").exists()


@pytest.fixture()
def broken_models(trained, tmp_path):
    """Copies of the trained model: NaN weights, a truncated weights file, a card that is a
    list, a card without its env section."""
    src = trained / "model"
    made = {}
    for name in ("nan", "truncated", "list_card", "no_env"):
        made[name] = tmp_path / name
        shutil.copytree(src, made[name])
    tensors = load_file(str(made["nan"] / "model.safetensors"))
    key = sorted(tensors)[0]
    tensors[key] = tensors[key].clone()
    tensors[key].view(-1)[0] = float("nan")
    save_file(tensors, str(made["nan"] / "model.safetensors"))
    raw = (made["truncated"] / "model.safetensors").read_bytes()
    (made["truncated"] / "model.safetensors").write_bytes(raw[: len(raw) // 2])
    (made["list_card"] / "model.json").write_text("[1, 2]")
    card = json.loads((made["no_env"] / "model.json").read_text())
    del card["env"]
    (made["no_env"] / "model.json").write_text(json.dumps(card))
    return made


@pytest.mark.parametrize(("name", "named"), [
    ("nan", "NaN/inf"), ("truncated", "not a readable safetensors file"),
    ("list_card", "a model card is a JSON object"), ("no_env", "no 'env' section")])
def test_a_broken_model_is_refused_by_every_loader(broken_models, tmp_path, name, named):
    path = broken_models[name]
    with pytest.raises(ValueError, match=named.replace("/", ".")):
        load_model(path)
    with pytest.raises(ExpertError, match=named.replace("/", ".")):
        load_expert(str(path), EnvSpec(rows=6, cols=6, agents=2))
    res = invoke("eval", "--policy", path, "--episodes", 2)
    assert_usage_error(res, "--policy", named)
    res = invoke("train", "--config", config(tmp_path), "--steps", 64, "--init-from", path,
                 "--out", tmp_path / "init", *QUIET)
    assert_usage_error(res, "--init-from", named)
    res = invoke("train", "--config", config(tmp_path), "--steps", 64, "--experts", path,
                 "--out", tmp_path / "experts", *QUIET)
    assert_usage_error(res, "expert", named)
    assert not (tmp_path / "init").exists() and not (tmp_path / "experts").exists()


# ---------------------------------------------------------------- 5. --minutes nan / inf
@pytest.mark.parametrize("minutes", ["nan", "inf", "0", "-1"])
def test_minutes_must_be_finite_and_positive(tmp_path, minutes):
    res = invoke("train", "--config", config(tmp_path), "--minutes", minutes,
                 "--out", tmp_path / "run", *QUIET)
    assert_usage_error(res, "--minutes")
    assert not (tmp_path / "run").exists()
    with pytest.raises(ValueError, match="minutes"):
        RunConfig(minutes=float(minutes))


# ---------------------------------------------------------------- 6. --out
def test_out_refuses_a_directory_holding_a_run_and_an_empty_path(trained, tmp_path):
    before = (trained / "metrics.csv").read_text()
    res = invoke("train", "--config", config(tmp_path), "--steps", 64, "--out", trained, *QUIET)
    assert_usage_error(res, "--out", "already holds a run", "--resume")
    assert (trained / "metrics.csv").read_text() == before
    res = invoke("train", "--config", config(tmp_path), "--steps", 64, "--out", "", *QUIET)
    assert_usage_error(res, "--out", "empty")
    # resuming into another directory that holds a run is refused too
    other = tmp_path / "other"
    other.mkdir()
    (other / "metrics.csv").write_text("update\n")
    res = invoke("train", "--resume", trained, "--steps", 128, "--out", other, *QUIET)
    assert_usage_error(res, "--out", "already holds a run")
    assert (trained / "metrics.csv").read_text() == before


@pytest.mark.parametrize("where", ["file", "file/sub", "/proc/drlaas-probe"])
def test_out_that_cannot_be_a_directory_is_refused_before_training(tmp_path, where):
    (tmp_path / "file").write_text("x")
    if where.startswith("/proc") and not os.path.isdir("/proc"):
        pytest.skip("no /proc")
    out = where if where.startswith("/") else tmp_path / where
    res = invoke("train", "--config", config(tmp_path), "--steps", 64, "--out", out, *QUIET)
    assert_usage_error(res, "--out")


@pytest.mark.parametrize(("name", "kind"), [("tb", "file"), ("best", "file"),
                                          ("config.json", "directory")])
def test_out_with_a_leftover_in_the_runs_way_is_refused_before_training(tmp_path, name, kind):
    """A file where the run makes a directory (or the reverse) failed mid-run, leaving rows
    without a checkpoint: it is refused up front and nothing is written."""
    out = tmp_path / "out"
    out.mkdir()
    (out / name).mkdir() if kind == "directory" else (out / name).write_text("x")
    res = invoke("train", "--config", config(tmp_path), "--steps", 64, "--out", out, *QUIET)
    assert_usage_error(res, "--out", f"({'a ' + kind})")
    assert sorted(p.name for p in out.iterdir()) == [name]


# ---------------------------------------------------------------- 7. grid bound
@pytest.mark.parametrize(("rows", "cols"), [(120, 120), (3000, 3000), (65, 64)])
def test_a_grid_beyond_the_cell_bound_is_refused_before_allocating(tmp_path, rows, cols):
    with pytest.raises(ValueError, match="grid"):
        EnvSpec(rows=rows, cols=cols)
    res = invoke("eval", "--policy", "bayes", "--grid", f"{rows}x{cols}", "--episodes", 2)
    assert_usage_error(res, "--grid", f"{MAX_CELLS:,}")
    res = invoke("train", "--config", config(tmp_path, env={"rows": rows, "cols": cols}),
                 "--steps", 64, "--out", tmp_path / "run", *QUIET)
    assert_usage_error(res, "--config", "grid")


def test_long_thin_grids_within_the_cell_bound_stay_allowed():
    assert EnvSpec(rows=6, cols=70, agents=2).num_cells == 420


# ---------------------------------------------------------------- 8. CMTL joint actions
def test_cmtl_with_many_agents_is_refused_before_allocating(tmp_path):
    spec = EnvSpec(rows=10, cols=10, agents=20)
    with pytest.raises(ValueError, match=r"5\*\*20"):
        make_observer(spec, ObservationSpec(kind="cmtl"))
    assert 5**8 <= MAX_JOINT_ACTIONS < 5**9
    make_observer(EnvSpec(rows=6, cols=6, agents=3), ObservationSpec(kind="cmtl"))
    cfg = config(tmp_path, preset="cmtl-3a-10x10", env={"rows": 10, "cols": 10, "agents": 20})
    res = invoke("train", "--config", cfg, "--steps", 64, "--out", tmp_path / "run", *QUIET)
    assert_usage_error(res, "joint actions", "dmtl or odmtl")
    assert not (tmp_path / "run").exists()


# ---------------------------------------------------------------- 9. clean errors
@pytest.mark.parametrize(("args", "sections", "named"), [
    (["--num-envs", "0"], {}, ["--num-envs", "num_envs"]),
    (["--num-envs", "-3"], {}, ["--num-envs", "num_envs"]),
    ([], {"run": {"bogus": 1}}, ["--config", "bogus"]),
    (["--eval-episodes", "0"], {}, ["--eval-episodes"]),
    (["--eval-episodes", "-2"], {}, ["--eval-episodes"]),
    ([], {"run": {"eval_episodes": 0}}, ["--config", "eval_episodes"]),
    (["--threads", "0"], {}, ["--threads"]),
    (["--threads", str(usable_cpus() + 1)], {}, ["--threads", "CPUs"]),
    (["--seed", "-1"], {}, ["--seed"]),
    ([], {"run": {"eval_seed": -1}}, ["--config", "eval_seed"]),
    ([], {"run": {"eval_every": 1.5}}, ["--config", "eval_every"]),
    ([], {"ppo": {"num_envs": 4.5}}, ["--config", "num_envs"]),
    ([], {"ppo": {"update_epochs": 1.5}}, ["--config", "update_epochs"]),
])
def test_bad_run_and_ppo_values_are_usage_errors_before_training(tmp_path, args, sections,
                                                                  named):
    res = invoke("train", "--config", config(tmp_path, **sections), "--steps", 64,
                 "--out", tmp_path / "run", *QUIET, *args)
    assert_usage_error(res, *named)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(("damage", "named"), [
    ("missing", "no such directory"),
    ("empty", "not a checkpoint directory"),
    ("model", "is a model directory"),
    ("truncated", "not a readable safetensors file"),
    ("bad_json", "not a JSON checkpoint state"),
    ("json_list", "expected a JSON object"),
    ("no_run", "state.json lacks"),
    ("step_text", "not numbers >= 0"),
    ("step_negative", "not numbers >= 0"),
    ("other_window", "do not fit its configuration"),
])
def test_resume_of_a_missing_or_damaged_checkpoint_is_a_usage_error(trained, tmp_path, damage,
                                                                    named):
    run = tmp_path / "run"
    if damage == "empty":
        run.mkdir()
    elif damage != "missing":
        shutil.copytree(trained, run)
    state = run / "checkpoint" / "state.json"
    if damage == "model":
        run = run / "model"
    elif damage == "truncated":
        f = run / "checkpoint" / "state.safetensors"
        f.write_bytes(f.read_bytes()[:100])
    elif damage == "bad_json":
        state.write_text('{"format": ')
    elif damage == "json_list":
        state.write_text("[1, 2]")
    elif damage == "no_run":
        doc = json.loads(state.read_text())
        del doc["run"]
        state.write_text(json.dumps(doc))
    elif damage.startswith("step_"):
        doc = json.loads(state.read_text())
        doc["counters"]["global_step"] = "64" if damage == "step_text" else -5
        state.write_text(json.dumps(doc))
    elif damage == "other_window":  # state.json of another network than the weights
        doc = json.loads(state.read_text())
        doc["observation"]["window"] = 3 if doc["observation"]["window"] == 5 else 5
        state.write_text(json.dumps(doc))
    res = invoke("train", "--resume", run, "--steps", 128, *QUIET)
    assert_usage_error(res, "--resume", named)


@pytest.mark.parametrize(("other", "named"), [
    ({"seed": 9}, "run.seed"),
    ({"ppo": {"horizon": 32}}, "ppo"),
])
def test_resume_refuses_another_runs_checkpoint_copied_into_a_run(trained, tmp_path, other,
                                                                  named):
    """Another run's checkpoint in a run directory would splice two curves into one
    metrics.csv and replace config.json and the model: refused, the directory untouched."""
    seed = other.get("seed")
    sections = {k: v for k, v in other.items() if k != "seed"}
    second = tmp_path / "second"
    args = ["train", "--config", config(tmp_path, "other", **sections), "--steps", 64,
            "--out", second, *QUIET] + (["--seed", seed] if seed is not None else [])
    assert invoke(*args).exit_code == 0
    run = tmp_path / "run"
    shutil.copytree(trained, run)
    shutil.rmtree(run / "checkpoint")
    shutil.copytree(second / "checkpoint", run / "checkpoint")
    before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()}
    res = invoke("train", "--resume", run, "--steps", 256, *QUIET)
    assert_usage_error(res, "--resume", "another run's", named)
    assert {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()} == before


def test_eval_refuses_an_intensity_the_readings_cannot_take():
    res = invoke("eval", "--policy", "bayes", "--intensity", "1e300", "--episodes", 2)
    assert_usage_error(res, "--intensity", "lower the intensity")
    with pytest.raises(ValueError, match="intensity"):
        EnvSpec(intensity=EnvSpec().intensity.fixed(1e30))
    EnvSpec(intensity=EnvSpec().intensity.fixed(1e12))  # the task spec's bound still fits


# ---------------------------------------------------------------- 10. / 11. / 12. messages
@pytest.mark.parametrize(("sections", "named"), [
    ({"ppo": {"learning_rate": "fast"}}, "learning_rate must be a finite number"),
    ({"ppo": {"horizon": "big"}}, "horizon must be an integer"),
    ({"ppo": {"num_minibatches": "2"}}, "num_minibatches must be an integer"),
    ({"ppo": {"horizon": 100.5}}, "horizon must be an integer"),
    ({"ppo": {"horizon": True}}, "horizon must be an integer"),
    ({"ppo": {"anneal_lr": 1}}, "anneal_lr must be true or false"),
    ({"env": {"intensity": {"kind": "fixed"}}}, "field intensity must be"),
    ({"env": {"intensity": [1e9]}}, "field intensity must be"),
    ({"env": {"intensity": 1e300}}, "lower the intensity"),
    ({"env": {"walls": 3}}, "field walls must be a pair"),
    ({"env": {"area_m": [math.nan, 1000]}}, "area_m must be a pair of finite numbers"),
    ({"env": {"area_m": [math.inf, 1000]}}, "area_m must be a pair of finite numbers"),
    ({"env": {"rows": 1, "cols": 1}}, "must be at least 2x2"),
])
def test_bad_config_values_are_named(tmp_path, sections, named):
    res = invoke("train", "--config", config(tmp_path, **sections), "--steps", 64,
                 "--out", tmp_path / "run", *QUIET)
    assert_usage_error(res, "--config", named)
    assert not (tmp_path / "run").exists()


def test_integer_fields_take_integers_only():
    for value in (100.5, 100.0, True, "100"):
        with pytest.raises(ValueError, match="horizon must be an integer"):
            PPOConfig(horizon=value)
    with pytest.raises(ValueError, match="total_steps must be an integer"):
        RunConfig(total_steps=100.5)
    assert PPOConfig(horizon=100).to_dict()["horizon"] == 100


def test_a_one_cell_grid_is_too_small_not_a_negative_wall_count():
    with pytest.raises(ValueError) as err:
        EnvSpec(rows=1, cols=1, agents=1)
    assert "at least 2x2" in str(err.value) and "at most -" not in str(err.value)


# ---------------------------------------------------------------- 14. cae --pos-weight
@pytest.mark.parametrize("weight", ["-1", "0", "nan", "inf"])
def test_cae_pos_weight_must_be_finite_and_positive(tmp_path, weight):
    res = invoke("cae", "train", "--out", tmp_path / "cae", "--grid", "6", "--walls", "1",
                 "--layouts", "8", "--epochs", "1", "--pos-weight", weight, "--no-progress")
    assert_usage_error(res, "--pos-weight")
    assert not (tmp_path / "cae").exists()
    with pytest.raises(ValueError, match="pos_weight"):
        train_cae(EnvSpec(rows=6, cols=6, walls=(1, 1)), layouts=8, epochs=1,
                  pos_weight=float(weight))



@pytest.mark.parametrize("args", [
    ["eval", "--policy", "bayes", "--grid", "4x4", "--walls", "8", "--episodes", "5"],
    ["eval", "--policy", "uniform", "--agents", "1", "--grid", "5x5", "--walls", "12",
     "--episodes", "5"],
])
def test_walls_that_leave_no_room_are_a_usage_error_not_a_hang(args):
    """Walls within the per-side bound can still enclose no area where the team and the target
    fit: the layout draws give up after MAX_LAYOUT_DRAWS and name the walls (this hung, or
    overflowed the stack, before)."""
    r = CliRunner().invoke(make_app(), args)
    assert r.exit_code == 2, r.output
    assert "of the wall layouts" in r.output and "--walls" in r.output


def test_env_with_no_room_for_the_team_raises_layout_error(monkeypatch):
    """Refused at construction by the share of layouts that fit (env.MIN_FIT_RATE); a reset
    that still meets MAX_LAYOUT_DRAWS misfits in a row gives up naming the walls."""
    from workers.mdrl import env as env_module
    from workers.mdrl.env import MAX_LAYOUT_DRAWS, LayoutError, TargetLocalizationEnv

    cramped = EnvSpec(rows=5, cols=5, walls=(12, 12))
    with pytest.raises(LayoutError, match="only 0% of the wall layouts"):
        TargetLocalizationEnv(cramped, 4, 0)
    monkeypatch.setattr(env_module, "MIN_FIT_RATE", 0.0)
    with pytest.raises(LayoutError, match=f"{MAX_LAYOUT_DRAWS} wall layouts in a row"):
        TargetLocalizationEnv(cramped, 4, 0)


def test_the_drlaas_command_keeps_the_normal_recursion_limit(tmp_path) -> None:
    """web3's py_ecc raises the recursion limit to 100,000 on import; with it, a card nested
    100,000 deep crashed `drlaas eval` with a segfault (exit 139) instead of a usage error."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    (tmp_path / "model.json").write_text("[" * 100_000 + "]" * 100_000)
    (tmp_path / "model.safetensors").write_bytes(b"")
    done = subprocess.run(
        [sys.executable, "-m", "drlaas", "eval", "--policy", str(tmp_path), "--episodes", "2"],
        capture_output=True, text=True, timeout=120, cwd=repo,
        env={**os.environ, "PYTHONPATH": str(repo), "COLUMNS": "1000"},  # no wrapped words
    )
    assert done.returncode == 2, (done.returncode, done.stderr[-500:])
    assert "not JSON" in done.stderr and "Traceback" not in done.stderr


@pytest.mark.parametrize("field,value", [
    ("area_m", (1e300, 1e300)),  # OverflowError traceback in Eq. 6's distances
    ("idle_limit", 10**30),  # numba int64 overflow at the first reset
    ("max_steps", 2**40),
    ("wall_mu_per_cm", -1.0),  # the message named neither of the two attenuation fields
])
def test_env_values_that_failed_later_are_refused_by_name(field, value):
    with pytest.raises(ValueError, match=field):
        EnvSpec(**{field: value})


@pytest.mark.parametrize("value", ["no", None, 1e30, 0])
def test_run_switches_take_booleans_only(value):
    """run.tensorboard "no" was read as true."""
    from workers.mdrl.train import RunConfigError

    for name in ("tensorboard", "progress"):
        with pytest.raises(RunConfigError, match=name):
            RunConfig(**{name: value})


@pytest.mark.parametrize("field", ["num_envs", "horizon"])
def test_ppo_sizes_are_bounded_by_name(field):
    """1e12 environments or steps per update ended in an allocation error naming no field."""
    with pytest.raises(ValueError, match=field):
        PPOConfig(**{field: 10**12})


def test_integer_weights_are_refused(tmp_path):
    """Integer or boolean weights were cast to float and loaded without a word."""
    import torch

    from workers.mdrl.modelio import load_weights

    model = tmp_path / "m"
    model.mkdir()
    save_file({"actor.w": torch.ones(3, dtype=torch.int64), "critic.b": torch.zeros(2)},
              str(model / "model.safetensors"))
    with pytest.raises(ValueError, match="floating point"):
        load_weights(model)
