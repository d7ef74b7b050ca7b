"""Baseline policies: validity, the oracle's lower bound, the Bayesian posterior, coverage."""

from __future__ import annotations

import numpy as np
import pytest

from workers.mdrl.baselines import (
    BASELINES,
    BayesPolicy,
    OraclePolicy,
    UniformPolicy,
    all_pairs_distances,
    make_baseline,
    snake_order,
)
from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.evaluate import evaluate
from workers.mdrl.spec import EnvSpec, IntensitySpec

SPECS = {
    "plain": EnvSpec(),
    "walls4": EnvSpec(walls=(1, 3)),
    "walls8": EnvSpec(moves=8, walls=(1, 3)),
    "one_agent_choice": EnvSpec(agents=1, intensity=IntensitySpec.choice([1e8, 5e8, 1e9])),
    "range_12x9": EnvSpec(
        rows=12, cols=9, agents=4, walls=(0, 2), moves=8, intensity=IntensitySpec.uniform(1e8, 1e9)
    ),
}


@pytest.mark.parametrize("spec_name", list(SPECS))
@pytest.mark.parametrize("name", BASELINES)
def test_policies_take_only_valid_actions(name, spec_name):
    # autoreset=True: episodes restart mid-run, so the policies' per-episode state is rebuilt too
    spec = SPECS[spec_name]
    env = TargetLocalizationEnv(spec, num_envs=24, seed=11, autoreset=True)
    policy = make_baseline(name, seed=5)
    policy.reset(env)
    ended = 0
    for _ in range(120):
        actions = policy.act(env)
        assert actions.shape == (24, spec.agents) and actions.dtype == np.int64
        mask = env.action_mask()
        chosen = np.take_along_axis(mask, actions[..., None], axis=2)[..., 0]
        assert chosen.all(), f"{name} took a masked action"
        result = env.step(actions)
        ended += 0 if result.episode is None else len(result.episode.index)
    assert ended > 24  # episodes did restart


@pytest.mark.parametrize("spec_name", ["plain", "walls4", "walls8", "range_12x9"])
def test_oracle_time_and_cost_equal_min_bfs_distance(spec_name):
    spec = SPECS[spec_name]
    report = evaluate(OraclePolicy(), spec, episodes=300, seed=2, batch=64)
    assert report.found.all()
    np.testing.assert_array_equal(report.time, report.lower_bound)
    np.testing.assert_array_equal(report.cost, report.lower_bound)
    assert report.lower_bound.min() >= 1


def test_all_pairs_distances_match_env_bfs():
    env = TargetLocalizationEnv(EnvSpec(moves=8, walls=(2, 3)), num_envs=16, seed=4)
    D = all_pairs_distances(env)
    b = np.arange(16)
    to_target = D[b, :, env.target].astype(np.int64)  # (16, C)
    reach = env.dist < env.spec.num_cells
    np.testing.assert_array_equal(to_target[reach], env.dist[reach])
    assert (to_target[~reach] >= 30000).all()


def test_snake_order_is_a_boustrophedon():
    order = snake_order(3, 4)
    np.testing.assert_array_equal(order, [0, 1, 2, 3, 7, 6, 5, 4, 8, 9, 10, 11])


def test_bayes_beats_random_beyond_chance():
    spec = EnvSpec()
    bayes = evaluate(BayesPolicy(), spec, episodes=200, seed=1)
    rand = evaluate(make_baseline("random", seed=1), spec, episodes=200, seed=1)
    assert bayes.success_rate == 1.0
    # 95% intervals far apart (not a lucky draw): time and cost
    assert bayes.summary["time_ci"][1] < rand.summary["time_ci"][0]
    assert bayes.summary["cost_ci"][1] < rand.summary["cost_ci"][0]
    # paired: bayes is faster in most episodes, not just on average
    assert (bayes.time < rand.time).mean() > 0.8


def test_uniform_always_finds_target_on_open_10x10():
    report = evaluate(UniformPolicy(), EnvSpec(), episodes=400, seed=3)
    assert report.found.all()
    assert report.time.max() <= 100
    # coverage, not luck: the target is found no later than the team can sweep the grid
    assert report.time.max() <= 34 + 18


def test_uniform_covers_walled_grids():
    report = evaluate(UniformPolicy(), EnvSpec(moves=8, walls=(1, 3)), episodes=200, seed=5)
    assert report.found.all()


def test_make_baseline_rejects_unknown_name():
    with pytest.raises(ValueError, match="unknown baseline 'greedy'"):
        make_baseline("greedy")


@pytest.mark.parametrize("moves", [4, 8])
def test_bayes_does_not_stall_between_equally_likely_cells(moves):
    # posterior split evenly over the cells around the agent: every single step raises the
    # expected distance, so a purely greedy searcher would idle forever
    spec = EnvSpec(agents=1, moves=moves)
    for seed in range(100):
        env = TargetLocalizationEnv(spec, num_envs=1, seed=seed, autoreset=False)
        r, c = divmod(int(env.pos[0, 0]), spec.cols)
        if 0 < r < spec.rows - 1 and 0 < c < spec.cols - 1:
            break
    offsets = [(0, -1), (0, 1)] if moves == 4 else [(-1, -1), (-1, 1), (1, -1), (1, 1)]
    candidates = [(r + dr) * spec.cols + (c + dc) for dr, dc in offsets]
    policy = BayesPolicy()
    policy.reset(env)
    split = np.zeros((1, spec.num_cells))
    split[0, candidates] = 1 / len(candidates)
    policy.belief.posterior = lambda env: split
    action = int(policy.act(env)[0, 0])
    assert action != 0
    assert env.next_cell[0, env.pos[0, 0], action] in candidates
