"""The Ch. 4 walls CAE: env layouts, the model and its files, and its embedding as an input."""

from __future__ import annotations

import json
import math
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from safetensors.torch import load_file
from typer.testing import CliRunner

from workers.mdrl.cae import (
    WallsCAE,
    WallsEmbedder,
    load_cae,
    load_cae_card,
    save_cae,
    train_cae,
    wall_layouts,
)
from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.evaluate import chunk_seed
from workers.mdrl.modelio import load_model
from workers.mdrl.networks import ActorCritic
from workers.mdrl.observations import ObservationSpec, channel_layout, make_observer
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.spec import EnvSpec
from workers.mdrl.train import RunConfig, Trainer

torch.set_num_threads(1)
SMALL = EnvSpec(rows=12, cols=12, agents=2, moves=8, walls=(1, 2))
ZOO = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def tiny_cae(tmp_path_factory):
    """A CAE trained for a few seconds on 12 x 12 layouts (d = 16), saved to a directory."""
    model, info = train_cae(SMALL, layouts=1000, epochs=15, embedding=16, seed=3, batch=32,
                            lr=3e-3)
    path = save_cae(tmp_path_factory.mktemp("cae") / "cae", model, SMALL, info)
    return path, model, info


def test_layouts_are_the_walls_the_env_draws_at_reset():
    spec = EnvSpec(rows=30, cols=30, agents=3, moves=8, walls=(1, 3))
    maps = wall_layouts(spec, 50, seed=9, chunk=25)
    for j in range(2):
        env = TargetLocalizationEnv(spec, num_envs=25, seed=chunk_seed(9, j))
        np.testing.assert_array_equal(maps[25 * j:25 * (j + 1)], env.walls.reshape(25, 30, 30))
    counts = maps.reshape(50, -1).sum(1)
    assert counts.min() > 0 and len(np.unique(counts)) > 5  # 1-3 walls of varied lengths
    np.testing.assert_array_equal(wall_layouts(spec, 50, seed=9, chunk=25), maps)
    assert not np.array_equal(wall_layouts(spec, 50, seed=10, chunk=25), maps)
    with pytest.raises(ValueError, match="no walls"):
        wall_layouts(spec.replace(walls=(0, 0)), 5)


@pytest.mark.parametrize("grid", [(30, 30), (11, 13)])
def test_encoder_and_decoder_shapes(grid):
    model = WallsCAE(grid, embedding=24)
    maps = torch.from_numpy(np.random.default_rng(0).random((5, *grid)) < 0.1)
    code = model.encoder(maps)
    assert code.shape == (5, 24) and code.abs().max() < 1  # tanh: bounded like the maps
    assert model.decoder(code).shape == (5, *grid)
    assert model(maps.reshape(5, 1, *grid)).shape == (5, 1, *grid)  # any leading dims
    with pytest.raises(ValueError, match="12x12"):
        WallsCAE((12, 12)).encoder(maps)


def test_cae_files_round_trip_to_identical_embeddings(tiny_cae, tmp_path, monkeypatch):
    path, model, info = tiny_cae
    assert sorted(p.name for p in path.iterdir()) == ["model.json", "model.safetensors"]
    card = load_cae_card(path)
    assert card["kind"] == "cae" and card["grid"] == [12, 12] and card["embedding"] == 16
    assert card["env"] == SMALL.to_dict() and card["heldout"] == json.loads(
        json.dumps(info["heldout"]))

    def forbidden(*args, **kwargs):
        raise AssertionError("loading a CAE must not unpickle")

    monkeypatch.setattr(pickle, "load", forbidden)
    monkeypatch.setattr(torch, "load", forbidden)
    loaded = load_cae(path)
    maps = torch.from_numpy(wall_layouts(SMALL, 40, seed=77))
    with torch.inference_mode():
        assert torch.equal(loaded.encoder(maps), model.encoder(maps))
        assert torch.equal(loaded(maps), model(maps))
    # a tampered card is refused, and a CAE is not a policy
    bad = tmp_path / "bad"
    shutil.copytree(path, bad)
    card["encoder_digest"] = "sha256:" + "0" * 64
    (bad / "model.json").write_text(json.dumps(card))
    with pytest.raises(ValueError, match="digest"):
        load_cae(bad)
    with pytest.raises(ValueError, match="not a policy"):
        load_model(path)


def test_a_short_training_beats_the_trivial_baselines_on_held_out_layouts(tiny_cae):
    _, _, info = tiny_cae
    held = info["heldout"]
    assert info["training"]["heldout_layouts"] == 100
    assert info["training"]["train_bce"][-1] < info["training"]["train_bce"][0]
    cae, empty, mean_map = held["cae"], held["empty"], held["mean_map"]
    assert empty["wall_iou"] == 0 and empty["bce"] is None
    assert math.isclose(empty["cell_error"], info["training"]["wall_density"], rel_tol=0.3)
    assert cae["cell_error"] < 0.75 * empty["cell_error"]
    assert cae["bce"] < 0.6 * mean_map["bce"]
    assert cae["wall_iou"] > 0.3


def test_embedder_caches_per_env_row_and_refreshes_when_the_walls_change(tiny_cae):
    path, model, _ = tiny_cae
    embedder = WallsEmbedder.load(path)
    env = TargetLocalizationEnv(SMALL, num_envs=6, seed=1)
    first = embedder.embed(env.walls)
    with torch.inference_mode():
        direct = model.encoder(torch.from_numpy(env.walls.reshape(6, 12, 12))).numpy()
    np.testing.assert_allclose(first, direct, atol=1e-6)
    assert embedder.encoded == 6
    np.testing.assert_array_equal(embedder.embed(env.walls), first)
    assert embedder.encoded == 6  # same walls: nothing re-encoded
    env._reset_rows(np.array([2]))  # a new episode in row 2 only
    again = embedder.embed(env.walls)
    assert embedder.encoded == 7
    np.testing.assert_array_equal(np.delete(again, 2, 0), np.delete(first, 2, 0))
    assert not np.array_equal(again[2], first[2])
    with pytest.raises(ValueError, match="12x12"):
        embedder.embed(np.zeros((2, 100), bool))


def test_the_embedding_replaces_the_downsized_walls_in_the_observation(tiny_cae):
    path, model, _ = tiny_cae
    plain = ObservationSpec("odmtl", window=3)
    spec = ObservationSpec("odmtl", window=3, walls_embedding=str(path), walls_embedding_size=16)
    assert "walls_embedding" not in plain.to_dict()  # cards without the option are unchanged
    assert ObservationSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(ValueError, match="walls_embedding"):
        ObservationSpec(walls_embedding="")
    before, after = channel_layout(SMALL, plain), channel_layout(SMALL, spec)
    assert "ds_walls" in before.actor and "ds_walls" not in after.actor
    assert "win_walls" in after.actor  # the windowed walls map stays (Fig. 4.2)
    assert after.actor[-2:] == ("walls_code_0", "walls_code_1")  # 16 values in 3 x 3 planes
    assert after.critic[-2:] == ("walls_code_0", "walls_code_1") and after.embedding == 16
    observer = make_observer(SMALL, spec)
    env = TargetLocalizationEnv(SMALL, num_envs=4, seed=2)
    actor, critic = observer.observe(env)
    code = observer.embedder.embed(env.walls)
    for stack, lead in ((actor, (4, 2)), (critic, (4,))):
        planes = stack[..., -2:, :, :].reshape(*lead, -1)
        np.testing.assert_array_equal(planes[..., :16], np.broadcast_to(
            code.reshape(4, *([1] * (len(lead) - 1)), 16), (*lead, 16)))
        assert not planes[..., 16:].any()
    # every other channel is the plain observation's channel of the same name
    base_actor, base_critic = make_observer(SMALL, plain).observe(env)
    for name in after.actor[:-2]:
        np.testing.assert_array_equal(actor[:, :, after.actor.index(name)],
                                      base_actor[:, :, before.actor.index(name)])
    for name in after.critic[:-2]:
        np.testing.assert_array_equal(critic[:, after.critic.index(name)],
                                      base_critic[:, before.critic.index(name)])
    # the networks feed the vector past the convolutions: changing it changes the outputs
    net = ActorCritic.for_observer(observer, SMALL.num_actions)
    assert net.actor.net[0].in_channels == len(after.actor) - 2
    obs = torch.from_numpy(actor)
    moved = obs.clone()
    moved[..., -2:, :, :] *= -1
    assert not torch.allclose(net.actor(obs), net.actor(moved))
    with pytest.raises(ValueError, match="walls_embedding_size"):
        make_observer(SMALL, ObservationSpec("odmtl", walls_embedding=str(path)))  # d = 128
    with pytest.raises(ValueError, match="10x10"):
        make_observer(SMALL.replace(rows=10, cols=10), spec)


def test_odmtl_training_with_the_embedding_saves_a_self_contained_model(tiny_cae, tmp_path,
                                                                       monkeypatch):
    path, _, _ = tiny_cae
    cae_dir = tmp_path / "cae"
    shutil.copytree(path, cae_dir)
    obs = ObservationSpec("odmtl", window=3, walls_embedding=str(cae_dir),
                          walls_embedding_size=16)
    ppo = PPOConfig(horizon=64, num_envs=8, update_epochs=2, num_minibatches=2)
    run = RunConfig(seed=0, total_steps=2 * ppo.batch_steps, eval_every=0, eval_episodes=8,
                    checkpoint_every=0, progress=False, tensorboard=False)
    trainer = Trainer(SMALL, obs, ppo, run, out=tmp_path / "run")
    start = [p.detach().clone() for p in trainer.agent.parameters()]
    trainer.train()
    assert trainer.update_idx == 2
    assert any(not torch.equal(a, b) for a, b in zip(start, trainer.agent.parameters(),
                                                     strict=True))
    model_dir = tmp_path / "run" / "model"
    card = json.loads((model_dir / "model.json").read_text())
    assert card["walls_encoder"]["digest"] == load_cae_card(cae_dir)["encoder_digest"]
    tensors = load_file(str(model_dir / "model.safetensors"))
    assert any(k.startswith("walls_encoder.") for k in tensors)
    shutil.rmtree(cae_dir)  # the model file carries its encoder: the CAE directory is not needed

    def forbidden(*args, **kwargs):
        raise AssertionError("model loading must not unpickle")

    monkeypatch.setattr(pickle, "load", forbidden)
    monkeypatch.setattr(torch, "load", forbidden)
    policy = load_model(model_dir)
    env_a = TargetLocalizationEnv(SMALL, 16, seed=5, autoreset=False)
    env_b = TargetLocalizationEnv(SMALL, 16, seed=5, autoreset=False)
    ours = trainer.policy()
    for _ in range(8):
        np.testing.assert_array_equal(policy.action_probs(env_a), ours.action_probs(env_b))
        a, b = policy.act(env_a), ours.act(env_b)
        np.testing.assert_array_equal(a, b)
        env_a.step(a)
        env_b.step(b)
    # as a DC expert on the same task it ranks actions by the same probabilities
    from workers.mdrl.experts import load_expert

    expert = load_expert(str(model_dir), SMALL)
    env = TargetLocalizationEnv(SMALL, 4, seed=6, autoreset=False)
    np.testing.assert_allclose(np.exp(expert.scores(env, np.arange(4))),
                               policy.action_probs(env), rtol=1e-5, atol=1e-7)


def _lenet_reference(tensors, prefix, x):
    """Table 3.1 LeNet written out with torch.nn.functional from raw safetensors weights."""
    t = {k[len(prefix):]: v for k, v in tensors.items() if k.startswith(prefix)}
    x = F.relu(F.conv2d(x, t["net.0.weight"], t["net.0.bias"], padding=1))
    x = F.max_pool2d(x, 2, 2, ceil_mode=True)
    x = F.relu(F.conv2d(x, t["net.3.weight"], t["net.3.bias"], padding=1)).flatten(1)
    x = F.relu(F.linear(x, t["net.6.weight"], t["net.6.bias"]))
    x = F.relu(F.linear(x, t["net.8.weight"], t["net.8.bias"]))
    return F.linear(x, t["net.10.weight"], t["net.10.bias"])


@pytest.mark.parametrize("name", ["odmtl-3a", "dmtl-2a"])
def test_zoo_models_without_embedding_load_and_act_as_their_weights_say(name):
    path = ZOO / name
    if not (path / "model.json").is_file():
        pytest.skip(f"zoo model {name} not present")
    policy = load_model(path)
    card = policy.card
    assert "walls_encoder" not in card and policy.observer.embedder is None
    assert sum(p.numel() for p in policy.agent.parameters()) == card["architecture"][
        "total_parameters"]
    tensors = load_file(str(path / "model.safetensors"))
    assert set(tensors) == set(policy.agent.state_dict())
    env = TargetLocalizationEnv(policy.env_spec, 16, seed=123, autoreset=False)
    for _ in range(5):
        actor, critic = policy.observer.observe(env)
        obs = torch.from_numpy(actor)
        with torch.inference_mode():
            ref = _lenet_reference(tensors, "actor.", obs.reshape(-1, *obs.shape[2:]))
            torch.testing.assert_close(policy.agent.actor(obs).reshape(ref.shape), ref)
            torch.testing.assert_close(policy.agent.value(torch.from_numpy(critic)),
                                       _lenet_reference(tensors, "critic.",
                                                        torch.from_numpy(critic)).squeeze(-1))
        env.step(policy.act(env))


def test_cae_commands_train_and_eval(tmp_path):
    from drlaas.cli import app

    out = tmp_path / "cae"
    runner = CliRunner()
    res = runner.invoke(app, ["cae", "train", "--out", str(out), "--grid", "12", "--walls", "1:2",
                              "--layouts", "200", "--epochs", "2", "--embedding", "8",
                              "--seed", "1", "--no-progress"])
    assert res.exit_code == 0, res.output
    assert "empty" in res.output and "mean_map" in res.output
    card = load_cae_card(out)
    assert card["embedding"] == 8 and card["env"]["walls"] == [1, 2]
    res = runner.invoke(app, ["cae", "eval", str(out), "--layouts", "30", "--json"])
    assert res.exit_code == 0, res.output
    shown = json.loads(res.stdout)
    assert shown["card"] == card["heldout"]
    assert set(shown["fresh"]) == {"cae", "empty", "mean_map"}
    assert {"cae", "cae_unseen", "empty", "mean_map"} == set(card["heldout"])
    res = runner.invoke(app, ["cae", "train", "--out", str(out), "--walls", "3:1"])
    assert res.exit_code != 0 and "--walls" in res.output


@pytest.mark.parametrize("options", [dict(kind="odmtl", belief=True),
                                     dict(kind="odmtl", critic="full", belief=True),
                                     dict(kind="dmtl", belief=True), dict(kind="cmtl")])
def test_every_map_channel_is_unchanged_by_the_embedding(tiny_cae, options):
    path, _, _ = tiny_cae
    plain = ObservationSpec(window=3, **options)
    spec = ObservationSpec(window=3, walls_embedding=str(path), walls_embedding_size=16,
                           **options)
    env = TargetLocalizationEnv(SMALL, num_envs=3, seed=4)
    for _ in range(3):
        env.step(np.argmax(env.action_mask(), -1))
    observer, base = make_observer(SMALL, spec), make_observer(SMALL, plain)
    (actor, critic), (b_actor, b_critic) = observer.observe(env), base.observe(env)
    code = observer.embedder.embed(env.walls)
    for got, want, names, base_names in ((actor, b_actor, observer.actor_channels,
                                          base.actor_channels),
                                         (critic[:, None], b_critic[:, None],
                                          observer.critic_channels, base.critic_channels)):
        codes = [i for i, c in enumerate(names) if c.startswith("walls_code_")]
        assert codes == list(range(len(names) - len(codes), len(names)))  # last planes
        flat = got[:, :, codes].reshape(*got.shape[:2], -1)
        np.testing.assert_array_equal(flat[..., :16], np.broadcast_to(
            code[:, None], (got.shape[0], got.shape[1], 16)))
        for i, name in enumerate(names[:codes[0]]):
            np.testing.assert_array_equal(got[:, :, i], want[:, :, base_names.index(name)])
        dropped = set(base_names) - set(names)
        assert dropped <= {"ds_walls"}


SHIPPED_CAES = {"cae-30x30": (30, 128, 7), "cae-10x10": (10, 32, 5)}
"""Shipped walls CAEs: grid side, d, and the window of the presets they serve."""


@pytest.mark.parametrize("name", sorted(SHIPPED_CAES))
def test_shipped_cae_holds_its_card_on_fresh_layouts(name):
    from workers.mdrl.cae import predict, reconstruction_figures

    path = ZOO / name
    if not (path / "model.json").is_file():
        pytest.skip(f"models/{name} not present")
    side, d, window = SHIPPED_CAES[name]
    assert (path / "model.safetensors").stat().st_size < 400 * 1024
    card = load_cae_card(path)
    spec = EnvSpec.from_dict(card["env"])
    assert (spec.rows, spec.cols, tuple(spec.walls), card["embedding"]) == (side, side, (1, 3), d)
    held = card["heldout"]
    assert held["cae"]["cell_error"] < 0.1 * held["empty"]["cell_error"]
    fresh = wall_layouts(spec, 500, seed=424242)
    got = reconstruction_figures(predict(load_cae(path), fresh), fresh)
    # 500 maps: the card's misclassified-cell rate and IoU must hold up to sampling
    assert got["cell_error"] < 2 * held["cae"]["cell_error"] + 1e-3
    assert got["wall_iou"] > held["cae"]["wall_iou"] - 0.03
    # and it serves a Ch. 4 observation (d rides in ceil(d / w^2) planes of w x w)
    obs = ObservationSpec("odmtl", window=window, walls_embedding=str(path),
                          walls_embedding_size=d)
    observer = make_observer(spec.replace(agents=3, moves=8), obs)
    planes = -(-d // (window * window))
    assert observer.actor_channels[-planes:] == tuple(f"walls_code_{i}" for i in range(planes))


def test_a_diverging_cae_run_is_an_error_and_saves_nothing(tmp_path):
    from drlaas.cli import app

    out = tmp_path / "cae"
    res = CliRunner().invoke(app, ["cae", "train", "--out", str(out), "--grid", "6",
                                   "--walls", "1:2", "--layouts", "200", "--epochs", "2",
                                   "--lr", "1e12", "--no-progress"])
    assert res.exit_code == 2, res.output
    assert "diverged" in res.output and "--lr" in res.output
    assert not out.exists()


def _damage(kind: str, path: Path) -> None:
    card = json.loads((path / "model.json").read_text())
    weights = path / "model.safetensors"
    if kind == "truncated":
        weights.write_bytes(weights.read_bytes()[: weights.stat().st_size // 2])
    elif kind == "no_grid":
        del card["grid"]
    elif kind == "other_embedding":
        card["embedding"] = 2 * card["embedding"]
    elif kind == "grid_text":
        card["grid"] = "12x12"
    elif kind == "nan_weights":  # a diverged CAE saved by an older version: digest matches
        from safetensors.torch import save_file

        from workers.mdrl.cae import tensor_digest

        tensors = load_file(str(weights))
        tensors = {k: torch.full_like(v, math.nan) if v.is_floating_point() else v
                   for k, v in tensors.items()}
        save_file(tensors, str(weights))
        enc = {k[len("encoder."):]: v for k, v in tensors.items() if k.startswith("encoder.")}
        card["encoder_digest"] = tensor_digest(enc)
    (path / "model.json").write_text(json.dumps(card))


@pytest.mark.parametrize("kind", ["truncated", "no_grid", "other_embedding", "grid_text",
                                  "nan_weights"])
def test_a_damaged_cae_directory_is_named_by_every_loader(tiny_cae, tmp_path, kind):
    """``load_cae``, ``drlaas cae eval`` and a config's walls_embedding refuse a damaged CAE
    with a ValueError / usage error naming the directory, never a traceback."""
    from drlaas.cli import app

    path = tmp_path / "cae"
    shutil.copytree(tiny_cae[0], path)
    _damage(kind, path)
    with pytest.raises(ValueError, match="cae"):
        load_cae(path)
    res = CliRunner().invoke(app, ["cae", "eval", str(path), "--layouts", "20"])
    assert res.exit_code == 2 and "PATH" in res.output, res.output
    with pytest.raises(ValueError):
        WallsEmbedder.load(path)


def test_a_policy_card_with_a_malformed_walls_encoder_is_refused():
    from workers.mdrl.cae import WallsEncoder, encoder_card, encoder_from_tensors

    enc = WallsEncoder((12, 12), 8)
    good = encoder_card(enc)
    assert encoder_from_tensors(good, enc.state_dict()).embedding == 8
    for card, named in (("models/cae-10x10", "must be an object"),
                        ({k: v for k, v in good.items() if k != "grid"}, "no 'grid'"),
                        ({**good, "embedding": "big"}, "unusable"),
                        ({**good, "embedding": 16}, "do not hold"),
                        # a few numbers that would ask for ~10 GB: refused before allocating
                        ({**good, "grid": [40000, 40000]}, "out of range"),
                        ({**good, "channels": [1] * 100_000}, "out of range"),
                        ({**good, "channels": [1024, 1024, 1024]}, "do not hold")):
        with pytest.raises(ValueError, match=named):
            encoder_from_tensors(card, enc.state_dict())


def test_a_cae_card_asking_for_a_huge_network_is_refused_before_building(tiny_cae, tmp_path):
    """``load_cae`` lays the card's network out on the meta device and compares it with the
    weights before building it: a card's grid / d / channels cannot make the loader allocate
    more than the weights file holds."""
    import resource

    path = tmp_path / "cae"
    shutil.copytree(tiny_cae[0], path)
    card = json.loads((path / "model.json").read_text())
    card["grid"], card["embedding"] = [1024, 1024], 1024
    (path / "model.json").write_text(json.dumps(card))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(ValueError, match="do not hold"):
        load_cae(path)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 500_000  # KiB
