"""Ch. 4 presets (4.7): the stated geometry, moves, wall count, rewards and PPO settings."""

from __future__ import annotations

import json

import numpy as np
import pytest

from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.observations import make_observer
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.presets import FAST_PPO, PRESETS, get_preset
from workers.mdrl.spec import EnvSpec
from workers.mdrl.trainingspec import trainingspec_json_schema


def wall_count(walls: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """(B,) walls per env: lines of each side whose first cell is a wall (walls never start at a
    corner line and never reach the far side, so each such line holds exactly one wall)."""
    grid = walls.reshape(-1, rows, cols)
    return (grid[:, 0, :].sum(1) + grid[:, -1, :].sum(1)
            + grid[:, :, 0].sum(1) + grid[:, :, -1].sum(1))


def test_all_sixteen_users_in_both_rewards_and_table41_variants_are_listed():
    names = {f"ch4-a{n}w{k}-{r}" for n in range(1, 5) for k in range(4) for r in ("sr", "sparse")}
    assert names <= set(PRESETS)
    assert {name + "-t41" for name in names} <= set(PRESETS)
    # the task spec's JSON Schema lists what the platform accepts
    assert all(f'"{name}"' in json.dumps(trainingspec_json_schema()) for name in names)


@pytest.mark.parametrize("name", ["ch4-a1w0-sr", "ch4-a3w3-sr", "ch4-a4w2-sparse"])
def test_presets_build_the_stated_env_and_step(name):
    p = get_preset(name)
    agents, walls = int(name[5]), int(name[7])
    spec = p.env
    assert (spec.rows, spec.cols, spec.cell_size_m) == (30, 30, (50.0, 50.0))
    assert spec.agents == agents and spec.walls == (walls, walls)
    assert spec.num_actions == 9 and spec.intensity.values == (1e9,)
    assert spec.reward == ("shaped" if name.endswith("-sr") else "sparse")
    assert spec.sparse_bonus == 50.0
    assert p.ppo == PPOConfig(**FAST_PPO)
    env = TargetLocalizationEnv(spec, 64, seed=0)
    assert (wall_count(env.walls, 30, 30) == walls).all()
    observer = make_observer(spec, p.observation)
    actor, critic = observer.observe(env)
    assert actor.shape[:3] == (64, agents, len(observer.actor_channels))
    assert actor.shape[3:] == (7, 7) and critic.shape[2:] == (7, 7)
    assert "win_walls" in observer.actor_channels and "ds_walls" in observer.critic_channels
    rng = np.random.default_rng(0)
    for _ in range(30):
        mask = env.action_mask()
        actions = (rng.random(mask.shape) * mask).argmax(-1)
        result = env.step(actions)
        actor, critic = observer.observe(env)
        assert np.isfinite(actor).all() and np.isfinite(critic).all()
        assert (wall_count(env.walls, 30, 30) == walls).all()  # also after resets
        moving = (actions != 0).sum(1)
        if spec.reward == "sparse":  # Eq. 9: -moves, + S when found
            assert (result.reward == -moving + 50.0 * result.terminated).all()
        else:  # Eq. 8: +1 closer / -1 otherwise, -moves
            assert np.isin(result.reward + moving, (1.0, -1.0)).all()


@pytest.mark.parametrize("name", ["ch4-a3w3-sr-10x10", "ch4-a1w0-sparse-10x10"])
def test_scaled_down_presets_are_the_ch4_users_on_10x10_cells_of_50m(name):
    """The 10 x 10 scale-down keeps the Ch. 4 setting (50 m cells, 8 moves, exact walls, the
    same reward) and adds the belief map, whose filter models the walls."""
    small, full = get_preset(name), get_preset(name.removesuffix("-10x10"))
    spec = small.env
    assert (spec.rows, spec.cols, spec.cell_size_m) == (10, 10, (50.0, 50.0))
    assert spec.replace(rows=30, cols=30, area_m=(1500.0, 1500.0)) == full.env
    assert small.observation.belief and small.observation.window == 5
    assert small.observation.walls
    env = TargetLocalizationEnv(spec, 16, seed=1)
    observer = make_observer(spec, small.observation)
    actor, critic = observer.observe(env)
    assert "belief" in " ".join(observer.actor_channels + observer.critic_channels)
    assert actor.shape[3:] == (5, 5) and np.isfinite(actor).all() and np.isfinite(critic).all()
    assert (wall_count(env.walls, 10, 10) == spec.walls[0]).all()


def test_table41_variant_is_table_41():
    p = get_preset("ch4-a3w3-sr-t41")
    assert p.ppo == PPOConfig(update_epochs=20)
    assert (p.ppo.learning_rate, p.ppo.clip_coef, p.ppo.ent_coef, p.ppo.gamma,
            p.ppo.gae_lambda, p.ppo.horizon) == (3e-4, 0.2, 0.01, 0.99, 0.95, 4000)
    assert p.env == get_preset("ch4-a3w3-sr").env


def test_wall_count_is_exact_even_when_draws_collide():
    # 6x6 has 16 non-corner side lines: 8 walls collide often, yet every episode has 8
    spec = EnvSpec(rows=6, cols=6, agents=1, moves=8, walls=(8, 8), wall_length=(1, 1))
    env = TargetLocalizationEnv(spec, 200, seed=2)
    assert (wall_count(env.walls, 6, 6) == 8).all()
    with pytest.raises(ValueError, match="at most 16 walls fit"):
        EnvSpec(rows=6, cols=6, walls=(0, 17))
