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


def _bfs_reference(env, b, source):
    """Steps from ``source`` to every cell of env b by a plain queue over ``env.next_cell``
    (the env's move table), UNREACHABLE where no path goes or the source is a wall."""
    from collections import deque

    from workers.mdrl.env import UNREACHABLE

    nxt, cells = np.asarray(env.next_cell)[b], env.spec.rows * env.spec.cols
    dist = np.full(cells, UNREACHABLE, dtype=np.int64)
    if env.walls[b, source]:
        return dist
    dist[source] = 0
    queue = deque([source])
    while queue:
        x = queue.popleft()
        for y in nxt[x, 1:]:
            if y >= 0 and dist[y] == UNREACHABLE:
                dist[y] = dist[x] + 1
                queue.append(y)
    return dist


def test_walking_steps_are_the_bfs_distances_of_the_layout():
    """env.walking_steps (one compiled BFS per source) against a plain BFS over the env's move
    table, walls and walled-off pockets included; baselines.all_pairs_distances is the same
    with FAR for no path."""
    from workers.mdrl.baselines import FAR, all_pairs_distances

    for moves in (4, 8):
        spec = EnvSpec(rows=9, cols=11, area_m=(900.0, 1100.0), agents=2, moves=moves,
                       walls=(1, 3))
        env = TargetLocalizationEnv(spec, num_envs=6, seed=moves)
        rng = np.random.default_rng(moves)
        cells = rng.integers(0, spec.rows * spec.cols, size=(6, 5))
        cells[0, 0] = np.flatnonzero(env.walls[0])[0]  # a source in a wall reaches nothing
        got = env.walking_steps(cells)
        for b in range(6):
            for j in range(5):
                np.testing.assert_array_equal(got[b, j], _bfs_reference(env, b, cells[b, j]))
        some = np.array([1, 4])  # the rows view of an expert adapter: those envs' walls
        np.testing.assert_array_equal(env.walking_steps(cells[some], some), got[some])
        pairs = all_pairs_distances(env, some)
        np.testing.assert_array_equal(
            np.take_along_axis(pairs, cells[some][:, :, None], axis=1),
            np.minimum(got[some], FAR))


def test_route_maps_are_the_expected_walking_distance_to_the_most_probable_cells():
    from workers.mdrl.observations import ROUTE_CELLS

    spec = EnvSpec(rows=12, cols=12, area_m=(600.0, 600.0), agents=2, moves=8, walls=(2, 2))
    obs_spec = ObservationSpec(kind="odmtl", window=5, readings="mean", scale="fixed",
                               belief=True, route=True, walls=True)
    observer = make_observer(spec, obs_spec)
    assert observer.actor_channels[-1] == "win_route"
    assert observer.critic_channels[-1] == "ds_route"
    env = TargetLocalizationEnv(spec, num_envs=8, seed=3)
    rng = np.random.default_rng(0)
    for _ in range(6):  # readings sharpen the posterior
        mask = env.action_mask()
        env.step(np.argmax(rng.random(mask.shape) * mask, axis=-1))
    actor, critic = observer.observe(env)
    post = BeliefFilter(spec).posterior(env)
    dist = np.array([[_bfs_reference(env, b, c) for c in range(144)] for b in range(8)])
    dist = np.minimum(dist, 144).astype(np.float64)  # (B, C, C); no path: the cap
    centre = env.past_pos(2)
    for b in range(8):
        top = np.argsort(-post[b], kind="stable")[:ROUTE_CELLS]
        w = post[b, top] / post[b, top].sum()
        g = (w[:, None] * dist[b, top]).sum(axis=0)  # (C,) expected steps to the source
        np.testing.assert_allclose(
            critic[b, -1].reshape(-1),
            np.minimum(g / 24.0, 1.0) @ downsize_matrix(12, 12, 5).T, rtol=1e-4, atol=1e-5)
        for i in range(2):
            r0, c0 = divmod(int(centre[b, i]), 12)
            here = g[env.pos[b, i]]
            for dr in range(-2, 3):
                for dc in range(-2, 3):
                    r, c = r0 + dr, c0 + dc
                    inside = 0 <= r < 12 and 0 <= c < 12
                    want = np.clip((here - g[r * 12 + c]) / 2, -1, 1) if inside else -1.0
                    if inside and env.walls[b, r * 12 + c]:
                        want = -1.0  # a wall cell is as far as the cap: always "away"
                    assert actor[b, i, -1, dr + 2, dc + 2] == pytest.approx(want, abs=1e-4)
    # a step toward the most probable cells is a step to a window cell with a positive value
    assert (actor[:, :, -1] > 0).any()


def test_route_needs_the_odmtl_belief_and_stays_out_of_old_cards():
    with pytest.raises(ValueError, match="route needs kind='odmtl' and belief=true"):
        ObservationSpec(kind="odmtl", route=True)
    with pytest.raises(ValueError, match="route needs"):
        ObservationSpec(kind="dmtl", belief=True, route=True)
    with pytest.raises(ValueError, match="route must be true or false"):
        ObservationSpec(kind="odmtl", belief=True, route=1)
    plain = ObservationSpec(kind="odmtl", belief=True)
    assert "route" not in plain.to_dict()  # cards and specs without it read as before
    on = ObservationSpec(kind="odmtl", belief=True, route=True)
    assert on.to_dict()["route"] is True and ObservationSpec.from_dict(on.to_dict()) == on


@pytest.mark.parametrize(("moves", "agents", "walls", "critic", "cae"), [
    (4, 1, (0, 0), "reduced", False),
    (8, 3, (1, 3), "full", False),
    (8, 2, (2, 2), "reduced", True),
])
def test_route_maps_on_other_set_ups(moves, agents, walls, critic, cae):
    """Any team, move set, walls or critic, and beside a walls CAE: the route planes sit
    before the embedding planes, in range, and the networks take the stacks."""
    import torch

    from workers.mdrl.networks import ActorCritic

    spec = EnvSpec(rows=10, cols=10, area_m=(500.0, 500.0), agents=agents, moves=moves,
                   walls=walls)
    obs_spec = ObservationSpec(
        kind="odmtl", window=5, readings="mean", scale="fixed", belief=True, route=True,
        walls=True, critic=critic,
        walls_embedding="models/cae-10x10" if cae else None,
        walls_embedding_size=32 if cae else 128)
    observer = make_observer(spec, obs_spec)
    layout = channel_layout(spec, obs_spec)
    assert observer.actor_channels == layout.actor
    route = observer.actor_channels.index("win_route")
    assert observer.actor_channels[route - 1] == "ds_belief"
    env = TargetLocalizationEnv(spec, num_envs=5, seed=2)
    rng = np.random.default_rng(1)
    for _ in range(4):
        actor, critic_obs = observer.observe(env)
        assert actor.shape[2:] == layout.actor_shape and critic_obs.shape[1:] == layout.critic_shape
        plane = actor[:, :, route]
        assert np.isfinite(plane).all() and plane.min() >= -1 and plane.max() <= 1
        assert (plane == 0).any()  # the agent's own cell (inside its window) reads 0
        mask = env.action_mask()
        env.step(np.argmax(rng.random(mask.shape) * mask, axis=-1))
    agent = ActorCritic(observer, spec.num_actions)
    logits = agent.logits(torch.from_numpy(actor.reshape(-1, *layout.actor_shape)),
                          torch.ones(5 * agents, spec.num_actions, dtype=torch.bool))
    assert torch.isfinite(logits).all()


def test_a_route_model_guides_a_task_of_another_grid_as_an_expert(tmp_path):
    """The expert adapter rebuilds a route model's inputs on a task of another size, for the
    few envs that follow it (an EnvRows view: their walls, not the first envs')."""
    from workers.mdrl.experts import load_expert
    from workers.mdrl.ppo import PPOConfig
    from workers.mdrl.train import RunConfig, Trainer

    small = EnvSpec(rows=6, cols=6, area_m=(300.0, 300.0), agents=2, moves=8, walls=(1, 1))
    obs_spec = ObservationSpec(kind="odmtl", window=3, readings="mean", scale="fixed",
                               belief=True, route=True, walls=True)
    ppo = PPOConfig(horizon=64, num_envs=8, update_epochs=1, num_minibatches=1)
    run = RunConfig(total_steps=64, eval_every=0, eval_episodes=4, checkpoint_every=0,
                    progress=False, tensorboard=False)
    Trainer(small, obs_spec, ppo, run, out=tmp_path / "run").train()
    task = EnvSpec(rows=9, cols=9, area_m=(450.0, 450.0), agents=3, moves=8, walls=(2, 2))
    expert = load_expert(str(tmp_path / "run" / "model"), task)
    env = TargetLocalizationEnv(task, num_envs=6, seed=0)
    rows = np.array([4, 1])
    scores = expert.scores(env, rows)
    assert scores.shape == (2, 3, task.num_actions)
    mask = env.action_mask()[rows]
    assert np.isfinite(scores[mask]).all()
    # the view's route planes are those envs' own (their walls and posteriors)
    from workers.mdrl.experts import EnvRows

    observer = make_observer(task, obs_spec)
    whole = observer.observe(env)[0][rows]
    view = make_observer(task, obs_spec).observe(EnvRows(env, rows))[0]
    route = observer.actor_channels.index("win_route")
    np.testing.assert_allclose(view[:, :, route], whole[:, :, route], atol=1e-5)


def test_the_belief_of_a_view_of_some_envs_is_theirs():
    """An expert guiding a few envs sees them through ``EnvRows``: the belief filter must fold
    their readings in under their own walls (it used the first envs' walls, so a belief
    expert in MEDC saw a wrong posterior)."""
    from workers.mdrl.experts import EnvRows

    spec = EnvSpec(rows=9, cols=9, area_m=(450.0, 450.0), agents=3, moves=8, walls=(2, 3))
    env = TargetLocalizationEnv(spec, num_envs=7, seed=5)
    rng = np.random.default_rng(2)
    for _ in range(3):
        mask = env.action_mask()
        env.step(np.argmax(rng.random(mask.shape) * mask, axis=-1))
    rows = np.array([5, 2, 6])
    whole = BeliefFilter(spec).posterior(env)[rows]
    view = BeliefFilter(spec).posterior(EnvRows(env, rows))
    np.testing.assert_allclose(view, whole, rtol=1e-9, atol=1e-12)


def test_walls_embedding_size_is_bounded_and_layouts_must_fit_often() -> None:
    """Two config values that passed validation and failed later (audit of 2026-12-03): a
    walls embedding of 10^6 (memory grew to 7-14 GB before any error), and walls that fit the
    team in 5% of the layouts (a run died mid-way, its checkpoint unable to get past it)."""
    import pytest

    from workers.mdrl.env import LayoutError, TargetLocalizationEnv
    from workers.mdrl.observations import MAX_WALLS_EMBEDDING, ObservationSpec
    from workers.mdrl.spec import EnvSpec

    with pytest.raises(ValueError, match="walls_embedding_size"):
        ObservationSpec(walls_embedding="cae", walls_embedding_size=MAX_WALLS_EMBEDDING + 1)
    assert ObservationSpec(walls_embedding="cae", walls_embedding_size=128).walls_embedding_size
    crowded = EnvSpec(rows=8, cols=8, area_m=(800.0, 800.0), agents=3, walls=(21, 21))
    with pytest.raises(LayoutError, match="of the wall layouts"):
        TargetLocalizationEnv(crowded, 4, seed=3)
    roomy = EnvSpec(rows=8, cols=8, area_m=(800.0, 800.0), agents=3, walls=(1, 3))
    TargetLocalizationEnv(roomy, 4, seed=3)


def test_a_fixed_scale_whose_unit_is_zero_is_refused() -> None:
    """intensity 1e-40 made the fixed scale's unit a float32 zero: NaN / inf observations, and
    training stopped with "diverged: lower the learning rate", naming the wrong cause."""
    import numpy as np
    import pytest

    from workers.mdrl.env import TargetLocalizationEnv
    from workers.mdrl.observations import ObservationSpec, make_observer
    from workers.mdrl.spec import EnvSpec, IntensitySpec

    fixed = ObservationSpec(kind="odmtl", window=3, scale="fixed")
    faint = EnvSpec(intensity=IntensitySpec("fixed", (1e-40,)), readings="expected")
    with pytest.raises(ValueError, match="fixed readings scale"):
        make_observer(faint, fixed)
    weak = EnvSpec(intensity=IntensitySpec("fixed", (1e-5,)), readings="expected")
    env = TargetLocalizationEnv(weak, 2, seed=0)
    actor, critic = make_observer(weak, fixed).observe(env)[:2]
    assert np.isfinite(actor).all() and np.isfinite(critic).all()
