"""A model card read by the CLI (``load_model``, ``drlaas eval --policy``) or pulled from the
store (``pull_model``) gets the task-spec bounds the worker applies to an expert's card, the
card size bound, and no symlink; a config file that is not an object is a usage error."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from backend.store import EmbeddedStore, InvalidContent
from backend.store.bundle import MAX_CARD_BYTES, pull_model, upload_model
from workers.mdrl import modelio
from workers.mdrl.commands.evaluate import eval_command
from workers.mdrl.commands.train import train
from workers.mdrl.modelio import load_model, save_model
from workers.mdrl.networks import ActorCritic
from workers.mdrl.observations import ObservationSpec, make_observer
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.presets import preset_from_dict
from workers.mdrl.rollout import PolicyHead
from workers.mdrl.spec import EnvSpec


def _model(path: Path, rows: int = 6, cols: int = 6) -> Path:
    env = EnvSpec(rows=rows, cols=cols, agents=1)
    obs = ObservationSpec(kind="odmtl", window=3)
    observer = make_observer(env, obs)
    head = PolicyHead(env.num_actions, env.agents, joint=bool(observer.joint_actions))
    return save_model(path, ActorCritic(observer, head.policy_actions), env, obs, PPOConfig())


def _edit_card(path: Path, **env: object) -> Path:
    card = json.loads((path / "model.json").read_text())
    card["env"].update(env)
    (path / "model.json").write_text(json.dumps(card))
    return path


def _invoke(*args: object) -> object:
    app = typer.Typer()
    app.command()(train)
    app.command("eval")(eval_command)
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _model(tmp_path_factory.mktemp("models") / "good")


def _copy(good: Path, dest: Path) -> Path:
    dest.mkdir(parents=True)
    for name in ("model.json", "model.safetensors"):
        (dest / name).write_bytes((good / name).read_bytes())
    return dest


@pytest.mark.parametrize(("field", "value"), [("max_steps", 10**9), ("idle_limit", 10**6)])
def test_a_card_beyond_the_task_spec_bounds_is_refused_by_load_and_eval(
    good: Path, tmp_path: Path, field: str, value: int
) -> None:
    bad = _edit_card(_copy(good, tmp_path / "bad"), **{field: value})
    with pytest.raises(ValueError, match=f"env.{field}"):
        load_model(bad)
    res = _invoke("eval", "--policy", bad, "--episodes", 1)
    assert res.exit_code == 2 and f"env.{field}" in " ".join(res.output.split())


def test_a_model_on_a_long_thin_grid_still_loads(tmp_path: Path) -> None:
    """The CLI trains grids up to EnvSpec's cell bound; its own models must load."""
    assert load_model(_model(tmp_path / "thin", rows=6, cols=70)).env_spec.cols == 70


def test_a_card_beyond_the_card_bound_is_refused(good: Path, tmp_path: Path) -> None:
    bad = _copy(good, tmp_path / "big")
    text = (bad / "model.json").read_text()
    (bad / "model.json").write_text(text[:-1] + " " * MAX_CARD_BYTES + "}")
    with pytest.raises(ValueError, match=f"more than {MAX_CARD_BYTES} bytes"):
        load_model(bad)
    assert modelio.MAX_CARD_BYTES == MAX_CARD_BYTES


@pytest.mark.parametrize("name", ["model.json", "model.safetensors"])
def test_symlinks_in_a_model_directory_are_refused(good: Path, tmp_path: Path, name: str) -> None:
    bad = _copy(good, tmp_path / "linked")
    (bad / name).unlink()
    os.symlink(good / name, bad / name)
    with pytest.raises(ValueError, match="a symlink"):
        load_model(bad)


def test_pull_refuses_a_card_beyond_the_bounds_and_writes_nothing(
    good: Path, tmp_path: Path
) -> None:
    store = EmbeddedStore(tmp_path / "ipfs", fsync=False)
    bad = _edit_card(_copy(good, tmp_path / "bad"), max_steps=10**9)
    cid = upload_model(store, bad)
    with pytest.raises(InvalidContent, match="env.max_steps"):
        pull_model(store, cid, tmp_path / "pulled")
    assert not list((tmp_path / "pulled").glob("*"))
    assert load_model(pull_model(store, upload_model(store, good), tmp_path / "ok"))


def test_a_config_that_is_not_an_object_is_a_usage_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="config must be a JSON/TOML object"):
        preset_from_dict([])  # type: ignore[arg-type]
    cfg = tmp_path / "cfg.json"
    cfg.write_text("[]")
    res = _invoke("train", "--config", cfg, "--steps", 1, "--out", tmp_path / "run",
                  "--no-progress", "--no-tensorboard")
    assert res.exit_code == 2, res.output
    assert "must be a JSON/TOML object" in " ".join(res.output.replace("│", " ").split())
