"""Observation options of issue 9 (per-cell mean, fixed scale, belief maps) on hand cases."""

from __future__ import annotations

import numpy as np
import pytest

from workers.mdrl.belief import BeliefFilter
from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.observations import (
    ObservationSpec,
    channel_layout,
    downsize_matrix,
    make_observer,
    reference_count,
)
from workers.mdrl.spec import EnvSpec, IntensitySpec


def _env_with(spec, readings_by_cell, agents_at):
    """A one-env state whose cells hold exactly the given lists of readings."""
    env = TargetLocalizationEnv(spec, num_envs=1, seed=0, autoreset=False)
    env.pos[0] = agents_at
    env.readings[0] = 0
    env.reading_sum[0] = 0
    env.visits[0] = 0
    for cell, values in readings_by_cell.items():
        env.readings[0, cell] = values[-1]
        env.reading_sum[0, cell] = sum(values)
        env.visits[0, cell] = len(values)
    return env


def test_mean_readings_average_every_reading_of_a_cell():
    spec = EnvSpec(rows=4, cols=4, area_m=(400.0, 400.0), agents=1)
    env = _env_with(spec, {0: [2.0, 4.0, 9.0], 5: [7.0]}, agents_at=[5])
    last = make_observer(spec, ObservationSpec(kind="dmtl"))
    mean = make_observer(spec, ObservationSpec(kind="dmtl", readings="mean"))
    ch = list(last.actor_channels).index("readings")
    got_last = last.observe(env)[0][0, 0, ch].reshape(-1)
    got_mean = mean.observe(env)[0][0, 0, ch].reshape(-1)
    # 'max' scale: each map divided by its own maximum
    np.testing.assert_allclose(got_last[[0, 5]], [9 / 9, 7 / 9])
    np.testing.assert_allclose(got_mean[[0, 5]], [5 / 7, 7 / 7])
    assert got_mean[[1, 2, 3, 4]].sum() == 0  # unvisited cells read 0


def test_fixed_scale_is_log_counts_over_the_reference_count():
    spec = EnvSpec(rows=4, cols=4, area_m=(400.0, 400.0), agents=1,
                   intensity=IntensitySpec.choice([1e7, 4e7]))
    # one cell side = 100 m = 1e4 cm from the strongest source: 4e7 * 200 / (4 pi 1e8)
    ref = 4e7 * 1.0 * 200.0 / (4 * np.pi * 1e8)
    assert reference_count(spec) == pytest.approx(ref)
    env = _env_with(spec, {3: [ref], 6: [0.5 * ref], 9: [10.0 * ref]}, agents_at=[6])
    obs = make_observer(spec, ObservationSpec(kind="dmtl", scale="fixed"))
    ch = list(obs.actor_channels).index("readings")
    got = obs.observe(env)[0][0, 0, ch].reshape(-1)
    want = np.log1p([ref, 0.5 * ref, 10 * ref]) / np.log1p(ref)
    np.testing.assert_allclose(got[[3, 6, 9]], want, rtol=1e-5)
    # unlike 'max', doubling every count does not leave the map unchanged
    env.readings *= 2
    assert not np.allclose(obs.observe(env)[0][0, 0, ch].reshape(-1)[[3, 6, 9]], want)


def test_belief_channels_show_the_filter_divided_by_its_maximum():
    spec = EnvSpec(rows=6, cols=6, area_m=(600.0, 600.0), agents=2)
    env = TargetLocalizationEnv(spec, num_envs=3, seed=4, autoreset=False)
    post = BeliefFilter(spec).posterior(env)
    norm = post / post.max(axis=1, keepdims=True)
    dmtl = make_observer(spec, ObservationSpec(kind="dmtl", belief=True))
    actor, critic = dmtl.observe(env)
    assert dmtl.actor_channels[-1] == dmtl.critic_channels[-1] == "belief"
    for i in range(2):
        np.testing.assert_allclose(actor[:, i, -1].reshape(3, -1), norm, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(critic[:, -1].reshape(3, -1), norm, rtol=1e-5, atol=1e-7)
    od = make_observer(spec, ObservationSpec(kind="odmtl", window=3, belief=True))
    actor, critic = od.observe(env)
    assert od.actor_channels[-2:] == ("win_belief", "ds_belief")
    ds = norm @ downsize_matrix(6, 6, 3).T
    np.testing.assert_allclose(actor[:, 0, -1].reshape(3, -1), ds, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(critic[:, -1].reshape(3, -1), ds, rtol=1e-4, atol=1e-6)
    # the window is centred on the agent (t = 0: past position = current position)
    r, c = divmod(int(env.pos[0, 1]), 6)
    grid = norm[0].reshape(6, 6)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            inside = 0 <= r + dr < 6 and 0 <= c + dc < 6
            want = grid[r + dr, c + dc] if inside else 0.0
            assert actor[0, 1, -2, dr + 1, dc + 1] == pytest.approx(want, rel=1e-5, abs=1e-7)


@pytest.mark.parametrize("kind", ["cmtl", "dmtl", "odmtl"])
def test_layouts_with_belief_match_what_the_observer_builds(kind):
    spec = EnvSpec(rows=5, cols=5, area_m=(500.0, 500.0), agents=2, moves=8, walls=(0, 1))
    obs_spec = ObservationSpec(kind=kind, readings="mean", scale="fixed", belief=True)
    layout = channel_layout(spec, obs_spec)
    env = TargetLocalizationEnv(spec, num_envs=4, seed=1)
    actor, critic = make_observer(spec, obs_spec).observe(env)
    assert actor.shape[2:] == layout.actor_shape and critic.shape[1:] == layout.critic_shape
    assert np.isfinite(actor).all() and np.isfinite(critic).all()


def test_options_reject_unknown_values():
    with pytest.raises(ValueError, match="readings must be 'last' or 'mean'"):
        ObservationSpec(readings="median")
    with pytest.raises(ValueError, match="scale must be 'max' or 'fixed'"):
        ObservationSpec(scale="log")
    with pytest.raises(ValueError, match="belief must be true or false"):
        ObservationSpec(belief="yes")
    spec = ObservationSpec(kind="dmtl", readings="mean", scale="fixed", belief=True)
    assert ObservationSpec.from_dict(spec.to_dict()) == spec


@pytest.mark.parametrize(("readings", "scale"), [("mean", "fixed"), ("mean", "max"),
                                                 ("last", "fixed"), ("last", "max")])
@pytest.mark.parametrize("kind", ["odmtl", "dmtl", "cmtl"])
def test_readings_maps_kept_between_steps_equal_a_fresh_computation(readings, scale, kind):
    """The observer updates its maps only at the agents' cells after one step; after resets,
    skipped steps (observe every other step), a second env and a restored env it still
    equals, bit for bit, what a fresh observer computes."""
    spec = EnvSpec(rows=8, cols=8, agents=3, walls=(0, 2), max_steps=12)
    osp = ObservationSpec(kind=kind, window=3, readings=readings, scale=scale)
    kept = make_observer(spec, osp)
    env, other = TargetLocalizationEnv(spec, 16, seed=1), TargetLocalizationEnv(spec, 5, seed=2)
    rng = np.random.default_rng(0)

    def act(e):
        keys = rng.random(e.action_mask().shape) * e.action_mask()
        e.step(keys.argmax(-1))

    def check(e):
        got = kept.observe(e)
        fresh = make_observer(spec, osp).observe(e)
        for a, b in zip(got, fresh, strict=True):
            np.testing.assert_array_equal(a, b)

    saved = None
    for step in range(40):  # several episodes (max_steps 12): resets on the way
        act(env)
        if step % 5 != 3:  # now and then two steps between observations
            check(env)
        if step % 7 == 0:
            act(other)
            check(other)
        if step == 10:
            saved = env.state_dict()
    env.load_state_dict(*saved)  # the same object jumps back in time
    check(env)
    assert len(kept._kept) == 2  # the two envs' maps were kept, not recomputed
