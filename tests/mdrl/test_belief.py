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


CH4 = EnvSpec(rows=30, cols=30, area_m=(1500.0, 1500.0), agents=3, moves=8, walls=(3, 3),
              reward="sparse")
"""The Ch. 4 size, where the filter keeps running sums instead of C x C matrices."""


@pytest.mark.parametrize("spec", [
    CH4,  # with the env's pair tables
    EnvSpec(rows=36, cols=36, area_m=(1800.0, 1800.0), agents=2, moves=8, walls=(1, 3)),  # none
    EnvSpec(rows=10, cols=10, agents=2),  # no walls
])
def test_unit_count_columns_are_the_env_reading_model_bit_for_bit(spec):
    """Column x of the unit counts (the filter's one new visited cell) is exactly what
    ``expected_counts`` gives with the source at each c, per layout."""
    env = TargetLocalizationEnv(spec, num_envs=4, seed=3)
    cells = np.arange(spec.num_cells)
    for e in range(4):
        walls = np.broadcast_to(env.walls[e], (len(cells), len(cells)))
        by_source = env.expected_counts(cells, walls, np.ones(len(cells)))  # (c, x)
        assert np.array_equal(env.unit_counts_at(cells, walls), by_source.T)


def test_running_sums_equal_a_filter_started_from_scratch_at_the_ch4_size():
    """The long-lived filter adds one column per new reading; a filter created at any step
    rebuilds the sums from the env's readings: both give the same posterior, across resets."""
    env = TargetLocalizationEnv(CH4, num_envs=6, seed=4, autoreset=True)
    belief, policy = BeliefFilter(CH4), RandomPolicy(seed=4)
    episodes = env.episode_id.copy()
    for _ in range(40):
        np.testing.assert_allclose(belief.posterior(env), BeliefFilter(CH4).posterior(env),
                                   rtol=1e-9, atol=1e-12)
        env.step(policy.act(env))
    assert (env.episode_id > episodes).any()  # some env started a new episode on the way


def test_a_state_restored_to_an_earlier_step_gets_its_posterior_back():
    """A state restored to an earlier step of the same episode (fewer visits) gets that
    step's posterior back."""
    env = TargetLocalizationEnv(CH4, num_envs=3, seed=5, autoreset=False)
    belief, policy = BeliefFilter(CH4), RandomPolicy(seed=5)
    env.step(policy.act(env))
    saved = {k: getattr(env, k).copy() for k in ("pos", "reading_sum", "visits", "readings")}
    earlier = belief.posterior(env)
    for _ in range(4):
        env.step(policy.act(env))
    belief.posterior(env)
    for k, v in saved.items():
        getattr(env, k)[...] = v
    np.testing.assert_allclose(belief.posterior(env), earlier, rtol=1e-9, atol=1e-12)
