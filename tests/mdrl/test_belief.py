"""The team posterior (workers/mdrl/belief.py) against a brute-force Bayes rule."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import poisson

from workers.mdrl.baselines import RandomPolicy
from workers.mdrl.belief import BeliefFilter, intensity_hypotheses
from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.spec import EnvSpec, IntensitySpec


class _RecordingNoise:
    """Stands in for the env's noise generator and keeps every reading it draws."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng, self.draws = rng, []

    def poisson(self, lam):
        out = self.rng.poisson(lam)
        self.draws.append(np.array(out, dtype=np.float64))
        return out


def _recorded_env(spec: EnvSpec, num_envs: int, seed: int):
    """An env whose every (cell, reading) pair per agent is logged, start readings included."""
    env = TargetLocalizationEnv(spec, num_envs=num_envs, seed=seed, autoreset=False)
    log = [[] for _ in range(num_envs)]
    for e in range(num_envs):  # the start readings happened in the constructor: one per agent
        for i in range(spec.agents):
            cell = env.pos[e, i]
            log[e].append((cell, env.reading_sum[e, cell] / env.visits[e, cell]))
    noise = _RecordingNoise(env.noise_rng)
    env.noise_rng = noise
    return env, log, noise


def _brute_force(env, e, taken, intensities):
    """P(target = c) by Bayes' rule over (c, I) with every reading's Poisson pmf."""
    C = env.spec.num_cells
    hyp = np.arange(C)
    walls = np.broadcast_to(env.walls[e], (C, C))
    logp = np.full((len(intensities), C), -np.log(len(intensities)))
    for k, intensity in enumerate(intensities):
        mu = env.expected_counts(hyp, walls, np.full(C, intensity))  # (target, cell)
        for cell, r in taken:
            logp[k] += poisson.logpmf(r, mu[:, cell])
    logp[:, env.walls[e] | (env.visits[e] > 0)] = -np.inf
    p = np.exp(logp - logp.max()).sum(0)
    return p / p.sum()


@pytest.mark.parametrize("walls", [(0, 0), (1, 1)])
def test_posterior_matches_brute_force_on_4x4_with_two_intensities(walls):
    spec = EnvSpec(rows=4, cols=4, area_m=(400.0, 400.0), agents=2, walls=walls,
                   intensity=IntensitySpec.choice([1e7, 1e8]))
    env, log, noise = _recorded_env(spec, num_envs=6, seed=3)
    belief, policy = BeliefFilter(spec), RandomPolicy(seed=0)
    policy.reset(env)
    # starting cells that share no start: agents start apart, so both readings were distinct
    for _ in range(4):
        got = belief.posterior(env)
        for e in np.flatnonzero(env.active):
            want = _brute_force(env, e, log[e], [1e7, 1e8])
            np.testing.assert_allclose(got[e], want, rtol=1e-4, atol=1e-9)  # float32 walls path
        actions = policy.act(env)
        live = env.active.copy()
        rows = np.flatnonzero(live)
        env.step(actions)
        drawn = noise.draws[-1]  # (live rows, N): one reading per agent, co-located ones too
        for k, e in enumerate(rows):
            if env.active[e]:
                for i in range(spec.agents):
                    log[e].append((env.pos[e, i], drawn[k, i]))


def test_posterior_excludes_walls_visited_cells_and_other_pockets():
    spec = EnvSpec(rows=6, cols=6, area_m=(600.0, 600.0), agents=1, moves=8, walls=(2, 3))
    env = TargetLocalizationEnv(spec, num_envs=32, seed=11, autoreset=False)
    p = BeliefFilter(spec).posterior(env)
    np.testing.assert_allclose(p.sum(1), 1.0)
    assert (p[env.walls] == 0).all()
    assert (p[env.visits > 0] == 0).all()
    # cells the agent cannot reach (walled-off pockets) hold no mass; the target always does
    assert (p[env.dist >= spec.num_cells] == 0).all()
    assert (p[np.arange(32), env.target] > 0).all()


def test_noise_free_readings_of_three_agents_pin_the_target_on_an_open_grid():
    # expected counts: each reading fixes the distance to the source; three fix the cell
    spec = EnvSpec(agents=3, readings="expected")
    env = TargetLocalizationEnv(spec, num_envs=64, seed=2, autoreset=False)
    p = BeliefFilter(spec).posterior(env)
    assert (p.argmax(1) == env.target).mean() > 0.95


def test_filter_follows_new_episodes_and_new_env_objects():
    spec = EnvSpec(rows=5, cols=5, area_m=(500.0, 500.0), agents=1, moves=8, walls=(1, 2))
    belief = BeliefFilter(spec)
    for seed in (1, 2):  # a second env object with other layouts: no stale geometry
        env = TargetLocalizationEnv(spec, num_envs=8, seed=seed, autoreset=True)
        fresh = BeliefFilter(spec)
        for _ in range(12):  # autoreset replaces layouts of finished episodes
            np.testing.assert_allclose(belief.posterior(env), fresh.posterior(env))
            env.step(RandomPolicy(seed).act(env))


def test_intensity_hypotheses_discretise_a_uniform_prior():
    vals, prior = intensity_hypotheses(EnvSpec(intensity=IntensitySpec.uniform(1e8, 9e8)), 4)
    np.testing.assert_allclose(vals, [2e8, 4e8, 6e8, 8e8])
    np.testing.assert_allclose(prior, 0.25)
