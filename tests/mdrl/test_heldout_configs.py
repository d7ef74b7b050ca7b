"""Configurations no other test names, tried as a user would: each was a traceback, a machine
run out of memory or a model silently overwritten, and is now a usage error naming the input."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.mdrl.test_cli_robustness import QUIET, assert_usage_error, config, invoke
from workers.mdrl.spec import EnvSpec

REPO = Path(__file__).resolve().parents[2]
CAE_10 = REPO / "models" / "cae-10x10"
POLICY = REPO / "models" / "odmtl-2a"
TINY_CAE = ["--grid", "6", "--walls", "1", "--layouts", "8", "--epochs", "1", "--no-progress"]


def test_an_episode_count_beyond_the_bound_is_refused_before_anything_is_allocated(tmp_path):
    """`drlaas eval --episodes 100000000000` built a list of every chunk and the per-episode
    arrays up front: the OOM killer ended it (23 GB) before the first step; `train
    --eval-episodes` did the same after the whole training run."""
    from workers.mdrl.baselines import OraclePolicy
    from workers.mdrl.evaluate import MAX_EPISODES, evaluate
    from workers.mdrl.train import RunConfig, RunConfigError

    too_many = MAX_EPISODES + 1
    with pytest.raises(ValueError, match="episodes"):
        evaluate(OraclePolicy(), EnvSpec(rows=6, cols=6, agents=2), too_many)
    with pytest.raises(RunConfigError, match="eval_episodes"):
        RunConfig(eval_episodes=too_many)
    assert_usage_error(invoke("eval", "--policy", "oracle", "--episodes", too_many),
                       "--episodes")
    res = invoke("train", "--config", config(tmp_path), "--steps", 64, "--eval-episodes",
                 too_many, "--out", tmp_path / "run", *QUIET)
    assert_usage_error(res, "--eval-episodes")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("command", ["train", "eval"])
def test_cae_layout_counts_beyond_memory_are_a_usage_error(tmp_path, command):
    """A layout count whose maps cannot be held was a MemoryError traceback (or, below the
    machine's size, an allocation the OOM killer ended)."""
    from workers.mdrl.cae import wall_layouts

    huge = ["--layouts", 10**12]
    args = (["train", "--out", tmp_path / "cae", *TINY_CAE, *huge] if command == "train"
            else ["eval", CAE_10, *huge])
    assert_usage_error(invoke("cae", *args), "layouts")
    assert not (tmp_path / "cae").exists()
    with pytest.raises(ValueError, match="layouts"):
        wall_layouts(EnvSpec(rows=6, cols=6, walls=(1, 1)), 10**12)


def test_a_negative_cae_seed_is_a_usage_error_naming_seed(tmp_path):
    """`cae eval --seed -1` crashed in numpy's SeedSequence; `cae train --seed -1` said only
    "expected non-negative integer"."""
    assert_usage_error(invoke("cae", "eval", CAE_10, "--layouts", 3, "--seed", -1), "--seed")
    res = invoke("cae", "train", "--out", tmp_path / "cae", *TINY_CAE, "--seed", -1)
    assert_usage_error(res, "--seed")
    assert not (tmp_path / "cae").exists()


def test_cae_train_refuses_an_out_it_cannot_or_must_not_write_before_training(tmp_path):
    """--out naming a file failed with a FileExistsError traceback after training; naming a
    policy model's directory replaced that model with the CAE without a word."""
    a_file = tmp_path / "notes.txt"
    a_file.write_text("keep me")
    for out in (a_file, a_file / "cae"):
        assert_usage_error(invoke("cae", "train", "--out", out, *TINY_CAE), "--out")
    assert a_file.read_text() == "keep me"
    policy = tmp_path / "policy"
    shutil.copytree(POLICY, policy)
    before = {p.name: p.read_bytes() for p in policy.iterdir()}
    assert_usage_error(invoke("cae", "train", "--out", policy, *TINY_CAE), "--out",
                       "not a walls CAE")
    assert {p.name: p.read_bytes() for p in policy.iterdir()} == before


def test_cae_train_still_rewrites_a_cae_directory(tmp_path):
    """Rebuilding a CAE in place is documented (docs/mdrl-core.md: the shipped CAEs)."""
    out = tmp_path / "cae"
    for _ in range(2):
        res = invoke("cae", "train", "--out", out, *TINY_CAE)
        assert res.exit_code == 0, res.output
    assert json.loads((out / "model.json").read_text())["kind"] == "cae"


@pytest.mark.parametrize(("key", "value"), [
    ("preset", ["odmtl-2a-10x10"]), ("preset", 3), ("name", 5), ("name", ["run"]),
    ("description", ["x"]),
])
def test_a_config_names_its_top_level_fields_of_the_wrong_type(tmp_path, key, value):
    """`preset = ["odmtl-2a-10x10"]` was refused as "unhashable type: 'list'"; a list or a
    number as name or description was taken, and named the run directory and the card."""
    doc = json.loads(config(tmp_path).read_text())
    path = tmp_path / "typed.json"
    path.write_text(json.dumps({**doc, key: value}))
    res = invoke("train", "--config", path, "--steps", 64, "--out", tmp_path / "run", *QUIET)
    assert_usage_error(res, "--config", f"{key} must be a string")
    assert not (tmp_path / "run").exists()


def test_a_reader_that_leaves_early_is_not_an_error():
    """`drlaas train --list-presets | head`: the list (~70 kB) outgrows the pipe, head
    leaves, and the write fails with EPIPE; that printed "error: [Errno 32] Broken pipe" and
    exited 1, as if the command had failed."""
    proc = subprocess.Popen([sys.executable, "-m", "drlaas", "train", "--list-presets"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO)
    assert proc.stdout is not None and proc.stdout.readline()
    proc.stdout.close()
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0 and b"Broken pipe" not in err, err.decode()


def test_an_expert_that_cannot_guide_is_named_by_its_flag_or_its_config(tmp_path):
    """An expert that does not load said "Invalid value: expert ...": the message named the
    model but not where it came from, --experts or the config's [experts] section."""
    missing = "nosuchmodel"  # relative, short: the message wraps at the terminal width
    res = invoke("train", "--config", config(tmp_path), "--steps", 64, "--experts", missing,
                 "--out", tmp_path / "a", *QUIET)
    assert_usage_error(res, "--experts", "'nosuchmodel'")
    res = invoke("train", "--config", config(tmp_path, experts={"models": [missing]}),
                 "--steps", 64, "--out", tmp_path / "b", *QUIET)
    assert_usage_error(res, "--config", "'nosuchmodel'")


def test_a_policy_card_listing_a_huge_walls_encoder_is_refused_before_it_is_built(tmp_path):
    """A model card's ``walls_encoder.channels`` is one conv layer each, built (on the meta
    device) before the weights are compared: 50,000 took 10 s and 400 MB, and a 1 MiB card
    holds ~500,000 (`drlaas eval --policy` on a pulled model). It is bounded as a CAE card
    is, and JSON ``true`` is no 1 there."""
    import torch
    from safetensors.torch import load, save

    from workers.mdrl.cae import check_cae_fields
    from workers.mdrl.modelio import load_model

    model = tmp_path / "model"
    model.mkdir()
    card = json.loads((POLICY / "model.json").read_text())
    card["observation"] |= {"walls_embedding": "bafyanyencoder", "walls_embedding_size": 4}
    card["walls_encoder"] = {"kind": "cae", "grid": [10, 10], "embedding": 4,
                             "channels": [1] * 100_000, "digest": "sha256:0"}
    (model / "model.json").write_text(json.dumps(card))
    weights = load((POLICY / "model.safetensors").read_bytes())
    (model / "model.safetensors").write_bytes(
        save(weights | {"walls_encoder.fc.weight": torch.zeros(1, 1)}))
    with pytest.raises(ValueError, match="walls_encoder.*out of range"):
        load_model(model)
    with pytest.raises(ValueError, match="out of range"):
        check_cae_fields({"grid": [10, 10], "embedding": True,
                          "architecture": {"channels": [8, 16]}})


def test_a_card_that_lies_about_its_network_is_named_as_such(tmp_path):
    """A card whose observation was edited (window 5 -> 7) loaded with torch's state-dict
    dump ("size mismatch for actor.net.6.weight ...") as the only explanation."""
    from workers.mdrl.modelio import load_model

    model = tmp_path / "model"
    shutil.copytree(POLICY, model)
    card = json.loads((model / "model.json").read_text())
    card["observation"]["window"] = 7
    (model / "model.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match="do not fit the network its card describes.*size "
                                         "mismatch for actor"):
        load_model(model)
    assert_usage_error(invoke("eval", "--policy", model, "--episodes", 5), "--policy",
                       "its card describes")


@pytest.mark.parametrize(("section", "changes", "named"), [
    ("env", {"sparse_bonus": -50.0}, "sparse_bonus"),
    ("env", {"sparse_bonus": 1e300}, "sparse_bonus"),
    ("observation", {"walls_embedding_size": 64}, "walls_embedding"),
])
def test_a_config_value_that_would_train_something_else_is_refused(tmp_path, section, changes,
                                                                   named):
    """A negative Eq. 9 bonus trained the team to avoid the source, 1e300 made the returns
    infinite, and a walls-embedding size without its CAE was dropped without a word: each
    trained a run other than the one asked for."""
    res = invoke("train", "--config", config(tmp_path, **{section: changes}), "--steps", 64,
                 "--out", tmp_path / "run", *QUIET)
    assert_usage_error(res, "--config", named)
    assert not (tmp_path / "run").exists()
