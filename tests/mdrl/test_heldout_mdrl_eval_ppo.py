"""Held-out pass of 2026-12-05 over `drlaas eval` and the PPO settings of a config file: a
model evaluated on another environment than its own is said so; PPO values that trained
forever, crashed with a traceback or trained silently wrong are usage errors naming the field."""

import json

import pytest

from tests.mdrl.test_cli_robustness import QUIET, assert_usage_error, config, invoke
from tests.mdrl.test_evaluate import _save_random_model
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.spec import EnvSpec


def test_eval_on_another_environment_than_the_model_s_says_so(tmp_path):
    """A model evaluated on another grid, team, walls, intensity or reading model printed its
    figures as if on its own: nothing said the set-up differed (a wall-blind model among walls
    was not even said to be blind). Now stderr names each difference, --json carries them,
    and stdout is unchanged; its own environment gives no note."""
    model = _save_random_model(tmp_path / "m", "odmtl", EnvSpec(rows=8, cols=8, agents=2))
    res = invoke("eval", "--policy", model, "--episodes", 2)
    assert res.exit_code == 0, res.output
    assert "note:" not in res.stderr
    res = invoke("eval", "--policy", model, "--episodes", 2, "--grid", "6x6", "--walls", "1",
                 "--agents", 3, "--readings", "expected")
    assert res.exit_code == 0, res.output
    note = " ".join(res.stderr.split())
    for text in ("--grid 8x8", "-> 6x6", "--agents 2 -> 3", "--walls 0-0 -> 1-1",
                 "--readings poisson -> expected", "blind to the walls"):
        assert text in note, note
    assert "note:" not in res.stdout
    res = invoke("eval", "--policy", model, "--episodes", 2, "--grid", "6x6", "--json")
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["trained_env"]["rows"] == 8 and out["env"]["rows"] == 6
    assert [d.split()[0] for d in out["differs_from_training"]] == ["--grid"]
    # a baseline has no training environment: no note
    res = invoke("eval", "--policy", "bayes", "--episodes", 2, "--grid", "6x6")
    assert res.exit_code == 0 and "note:" not in res.stderr


@pytest.mark.parametrize(("field", "value"), [
    ("update_epochs", 10**12),  # one update that never ends: --minutes cannot stop it
    ("learning_rate", 1e300),  # a traceback in Adam's first step (float32 overflow)
    ("learning_rate", 1e39),
    ("clip_coef", 1e300),  # a traceback in the first loss (clamp bounds overflow)
    ("vf_coef", -5.0),  # trained, maximising the value error, without a word
    ("ent_coef", -0.5),  # trained, rewarding certainty, without a word
])
def test_ppo_values_that_cannot_train_are_refused_naming_the_field(tmp_path, field, value):
    with pytest.raises(ValueError, match=field):
        PPOConfig(**{field: value})
    res = invoke("train", "--config", config(tmp_path, ppo={field: value}), "--steps", 64,
                 "--out", tmp_path / "run", *QUIET)
    assert_usage_error(res, "--config", field)
    assert not (tmp_path / "run").exists()


def test_ppo_bounds_keep_every_preset_and_the_thesis_values():
    from workers.mdrl.presets import PRESETS
    from workers.mdrl.trainingspec import PPO_RULES

    for preset in PRESETS.values():
        PPOConfig.from_dict(preset.ppo.to_dict())
    # the values a task spec accepts at its bounds are accepted here too
    for field in ("update_epochs", "learning_rate", "clip_coef", "ent_coef", "vf_coef"):
        for bound in (PPO_RULES[field].lo, PPO_RULES[field].hi):
            PPOConfig(**{field: bound})


def test_a_json_config_giving_a_key_twice_is_refused(tmp_path):
    """json keeps the last of a repeated key without a word: this config trained CMTL."""
    path = tmp_path / "twice.json"
    path.write_text('{"preset": "odmtl-2a-10x10", "run": {"seed": 1}, '
                    '"preset": "cmtl-2a-10x10"}')
    res = invoke("train", "--config", path, "--steps", 64, "--out", tmp_path / "run", *QUIET)
    assert_usage_error(res, "--config", "'preset' given twice")
    assert not (tmp_path / "run").exists()


def test_train_out_refuses_a_model_directory(tmp_path):
    """`--out MODEL_DIR` wrote a whole run (checkpoint/, metrics.csv, model/) among a model's
    two files; `cae train --out` already refused a policy's directory."""
    model = _save_random_model(tmp_path / "m", "odmtl", EnvSpec(rows=6, cols=6, agents=2))
    before = sorted(p.name for p in model.iterdir())
    res = invoke("train", "--config", config(tmp_path), "--steps", 64, "--out", model, *QUIET)
    assert_usage_error(res, "--out", "model directory")
    assert sorted(p.name for p in model.iterdir()) == before
