"""Observation builders against hand-computed maps and a slow per-env reference."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy import ndimage

from workers.mdrl.observations import (
    ObservationSpec,
    _Kept,
    decode_joint,
    downsize_matrix,
    encode_joint,
    joint_mask,
    make_observer,
)


def filled(shape, dtype=np.float64, at=None, flat=None, value=1.0):
    """A zero array with ``value`` written at index ``at`` (or flat index ``flat``)."""
    a = np.zeros(shape, dtype)
    if flat is not None:
        a.flat[flat] = value
    else:
        a[at] = value
    return a


def make_spec(rows=5, cols=5, agents=2, walls=(0, 0)):
    return SimpleNamespace(rows=rows, cols=cols, agents=agents, walls=walls)


def make_env(spec, pos, readings=None, visits=None, walls=None, past=None):
    """A hand-made state with the attributes the builders read (docs/mdrl-core.md)."""
    pos = np.asarray(pos, dtype=np.int64)
    b, c = pos.shape[0], spec.rows * spec.cols
    past = pos if past is None else np.asarray(past, dtype=np.int64)
    calls = []

    def past_pos(k):
        calls.append(k)
        return past

    return SimpleNamespace(
        spec=spec,
        pos=pos,
        readings=np.zeros((b, c), np.float32) if readings is None else readings.astype(np.float32),
        visits=np.ones((b, c), np.float32) if visits is None else visits.astype(np.float32),
        walls=np.zeros((b, c), bool) if walls is None else np.asarray(walls, bool),
        past_pos=past_pos,
        past_calls=calls,
    )


def random_env(rng, spec, b):
    c = spec.rows * spec.cols
    pos = rng.integers(0, c, (b, spec.agents))
    pos[0, :] = pos[0, 0]  # one env with every agent stacked on one cell
    # past positions within one step per axis of the current ones (agents move <= 1 cell)
    r, col = np.divmod(pos, spec.cols)
    pr = np.clip(r + rng.integers(-1, 2, pos.shape), 0, spec.rows - 1)
    pc = np.clip(col + rng.integers(-1, 2, pos.shape), 0, spec.cols - 1)
    readings = rng.random((b, c)).astype(np.float32) * (rng.random((b, c)) < 0.3)
    readings[1] = 0.0  # an env with no reading yet
    visits = rng.integers(0, 4, (b, c)).astype(np.float32)
    walls = rng.random((b, c)) < 0.2
    return make_env(spec, pos, readings, visits, walls, pr * spec.cols + pc)


# ----------------------------------------------------------------------------- slow reference


def norm(m):
    return m / m.max() if m.max() > 0 else m


def ref_downsize(m, w):
    g = ndimage.gaussian_filter(m.astype(np.float64), 1.0, mode="nearest")
    return ndimage.zoom(
        g, (w / m.shape[0], w / m.shape[1]), order=1, mode="nearest", grid_mode=False
    )


def ref_window(m, centre, w):
    p = w // 2
    padded = np.pad(m, p)
    r, c = centre
    return padded[r : r + w, c : c + w]


def reference(spec, obs, env):
    """Loops over envs and agents, straight from the thesis' map definitions."""
    rows, cols, n = spec.rows, spec.cols, spec.agents
    w = obs.window
    with_walls = obs.walls if obs.walls is not None else spec.walls[1] > 0
    actors, critics = [], []
    past = env.past_pos(w // 2) if obs.kind == "odmtl" else None
    for b in range(env.pos.shape[0]):
        loc = []
        for i in range(n):
            m = np.zeros((rows, cols))
            m[divmod(int(env.pos[b, i]), cols)] = 1
            loc.append(m)
        counts = sum(loc)
        rd = norm(env.readings[b].reshape(rows, cols).astype(np.float64))
        vs = norm(env.visits[b].reshape(rows, cols).astype(np.float64))
        wl = env.walls[b].reshape(rows, cols).astype(np.float64)
        tail = [rd, vs] + ([wl] if with_walls else [])
        if obs.kind == "cmtl":
            actors.append(np.stack(loc + tail)[None])
            critics.append(np.stack(loc + tail))
            continue
        per_agent = []
        for i in range(n):
            other = [norm(counts - loc[i])] if n > 1 else []
            if obs.kind == "dmtl":
                per_agent.append(np.stack([loc[i]] + other + tail))
            else:
                centre = divmod(int(past[b, i]), cols)
                maps = [
                    ref_window(loc[i], centre, w),
                    ref_window(rd, centre, w),
                    ref_downsize(loc[i], w),
                ] + [ref_downsize(o, w) for o in other]
                maps += [ref_downsize(rd, w), ref_downsize(vs, w)]
                if with_walls:
                    maps += [ref_window(wl, centre, w), ref_downsize(wl, w)]
                per_agent.append(np.stack(maps))
        actors.append(np.stack(per_agent))
        if obs.kind == "dmtl":
            critics.append(np.stack([norm(counts)] + tail))
        else:
            critics.append(np.stack([ref_downsize(m, w) for m in [norm(counts)] + tail]))
    return np.stack(actors), np.stack(critics)


@pytest.mark.parametrize("kind", ["cmtl", "dmtl", "odmtl"])
@pytest.mark.parametrize("agents", [1, 3])
@pytest.mark.parametrize("walls", [False, True])
def test_batched_observe_matches_per_env_reference(kind, agents, walls):
    rng = np.random.default_rng(7)
    spec = make_spec(rows=7, cols=9, agents=agents, walls=(0, 3) if walls else (0, 0))
    obs = ObservationSpec(kind, window=5)
    env = random_env(rng, spec, b=6)
    observer = make_observer(spec, obs)
    actor, critic = observer.observe(env)
    ref_a, ref_c = reference(spec, obs, env)
    assert actor.dtype == np.float32 and critic.dtype == np.float32
    assert actor.shape == (6, 1 if kind == "cmtl" else agents) + observer.actor_shape
    assert critic.shape == (6,) + observer.critic_shape
    np.testing.assert_allclose(actor, ref_a, atol=1e-5)
    np.testing.assert_allclose(critic, ref_c, atol=1e-5)


# ----------------------------------------------------------------------------- hand-computed


def test_dmtl_maps_by_hand():
    spec = make_spec(rows=4, cols=4, agents=3)
    readings = filled((1, 16), at=np.s_[0, [0, 5]], value=[2.0, 4.0])
    visits = filled((1, 16), at=np.s_[0, [0, 5, 6]], value=[1, 2, 1])
    # agents 1 and 2 share cell 6; agent 0 is at cell 5
    env = make_env(spec, [[5, 6, 6]], readings, visits)
    actor, critic = make_observer(spec, ObservationSpec("dmtl")).observe(env)
    a = actor[0].reshape(3, 4, 16)
    assert a[0, 0, 5] == 1 and a[0, 0].sum() == 1
    # others of agent 0: two agents on cell 6 -> normalised to 1
    expected = filled(16, at=np.s_[6], value=1.0)
    np.testing.assert_allclose(a[0, 1], expected)
    # others of agent 1: agent 0 on 5 and agent 2 on 6 -> 1 each, max 1
    expected = filled(16, at=np.s_[[5, 6]], value=1.0)
    np.testing.assert_allclose(a[1, 1], expected)
    expected = filled(16, at=np.s_[[0, 5]], value=[0.5, 1.0])
    np.testing.assert_allclose(a[2, 2], expected)
    expected = filled(16, at=np.s_[[0, 5, 6]], value=[0.5, 1.0, 0.5])
    np.testing.assert_allclose(a[1, 3], expected)
    c = critic[0].reshape(3, 16)
    expected = filled(16, at=np.s_[[5, 6]], value=[0.5, 1.0])  # counts 1 and 2, max 2
    np.testing.assert_allclose(c[0], expected)


def test_dmtl_others_map_when_an_agent_shares_a_cell_with_one_other():
    spec = make_spec(rows=4, cols=4, agents=3)
    env = make_env(spec, [[3, 3, 9]])  # agents 0, 1 on cell 3, agent 2 on cell 9
    actor, _ = make_observer(spec, ObservationSpec("dmtl")).observe(env)
    others = actor[0, :, 1].reshape(3, 16)
    expected = filled(16, at=np.s_[[3, 9]], value=1.0)  # one other agent on each cell
    np.testing.assert_allclose(others[0], expected)
    expected = filled(16, at=np.s_[3], value=1.0)  # both others on cell 3: 2 / 2
    np.testing.assert_allclose(others[2], expected)


def test_odmtl_window_centred_on_past_position_and_zero_off_grid():
    spec = make_spec(rows=5, cols=5, agents=2)
    readings = np.arange(25, dtype=np.float32)[None] + 1  # max 25
    # agent 0 now at (0, 1), was at (0, 0) one step ago; agent 1 at (2, 2) both times
    env = make_env(spec, [[1, 12]], readings, past=[[0, 12]])
    observer = make_observer(spec, ObservationSpec("odmtl", window=3))
    actor, _ = observer.observe(env)
    assert env.past_calls == [1]  # t - (w-1)/2 with w = 3
    win_loc, win_read = actor[0, 0, 0], actor[0, 0, 1]
    expected = filled((3, 3), at=np.s_[1, 2], value=1.0)  # one column right of the centre
    np.testing.assert_array_equal(win_loc, expected)
    expected = np.array([[0, 0, 0], [0, 1, 2], [0, 6, 7]], dtype=np.float32) / 25
    np.testing.assert_allclose(win_read, expected)
    expected = np.array([[7, 8, 9], [12, 13, 14], [17, 18, 19]], dtype=np.float32) / 25
    np.testing.assert_allclose(actor[0, 1, 1], expected)
    assert actor[0, 1, 0, 1, 1] == 1 and actor[0, 1, 0].sum() == 1


def test_odmtl_window_of_5_looks_two_steps_back():
    spec = make_spec(rows=7, cols=7, agents=1)
    env = make_env(spec, [[24]], past=[[10]])  # now (3, 3), two steps ago (1, 3)
    actor, _ = make_observer(spec, ObservationSpec("odmtl", window=5)).observe(env)
    assert env.past_calls == [2]
    expected = filled((5, 5), at=np.s_[4, 2], value=1.0)
    np.testing.assert_array_equal(actor[0, 0, 0], expected)


def test_maps_are_normalised_before_downsizing():
    spec = make_spec(rows=6, cols=6, agents=1)
    readings = filled((1, 36), np.float32, at=np.s_[0, 14], value=1000.0)
    env = make_env(spec, [[0]], readings)
    observer = make_observer(spec, ObservationSpec("odmtl", window=3))
    actor, critic = observer.observe(env)
    unit = filled((6, 6), flat=14, value=1.0)
    np.testing.assert_allclose(critic[0, 1], ref_downsize(unit, 3), atol=1e-6)
    assert 0 < actor[0, 0, 3].max() < 1  # downsized after normalising: a blurred peak


def test_zero_readings_stay_zero():
    spec = make_spec(rows=5, cols=5, agents=2)
    env = make_env(spec, [[0, 24]])
    for kind in ("cmtl", "dmtl", "odmtl"):
        actor, critic = make_observer(spec, ObservationSpec(kind)).observe(env)
        assert np.all(np.isfinite(actor)) and np.all(np.isfinite(critic))


# ----------------------------------------------------------------------------- channels, walls


@pytest.mark.parametrize(
    "kind,agents,actor_c,critic_c",
    [
        ("cmtl", 1, 3, 3),
        ("cmtl", 3, 5, 5),
        ("cmtl", 5, 7, 7),
        ("dmtl", 1, 3, 3),
        ("dmtl", 2, 4, 3),
        ("odmtl", 1, 5, 3),
        ("odmtl", 3, 6, 3),
    ],
)
def test_channel_counts_are_the_thesis_without_walls(kind, agents, actor_c, critic_c):
    observer = make_observer(make_spec(10, 10, agents), ObservationSpec(kind, window=3))
    assert observer.actor_shape[0] == actor_c == len(observer.actor_channels)
    assert observer.critic_shape[0] == critic_c == len(observer.critic_channels)
    hw = (3, 3) if kind == "odmtl" else (10, 10)
    assert observer.actor_shape[1:] == hw and observer.critic_shape[1:] == hw


@pytest.mark.parametrize(
    "env_walls,flag,expected",
    [
        ((0, 0), None, False),
        ((0, 2), None, True),
        ((1, 3), False, False),
        ((0, 0), True, True),
    ],
)
def test_wall_maps_follow_the_flag_or_the_env(env_walls, flag, expected):
    spec = make_spec(10, 10, 2, walls=env_walls)
    for kind, extra_actor, extra_critic in [("cmtl", 1, 1), ("dmtl", 1, 1), ("odmtl", 2, 1)]:
        base = make_observer(make_spec(10, 10, 2), ObservationSpec(kind, walls=False))
        observer = make_observer(spec, ObservationSpec(kind, walls=flag))
        assert observer.actor_shape[0] == base.actor_shape[0] + extra_actor * expected
        assert observer.critic_shape[0] == base.critic_shape[0] + extra_critic * expected


def test_windowed_walls_map():
    spec = make_spec(rows=5, cols=5, agents=1, walls=(1, 2))
    walls = filled((1, 25), bool, at=np.s_[0, [7, 8, 9]], value=True)  # row 1, cols 2..4
    env = make_env(spec, [[13]], walls=walls)  # agent at (2, 3)
    observer = make_observer(spec, ObservationSpec("odmtl"))
    actor, critic = observer.observe(env)
    assert observer.actor_channels[-2:] == ("win_walls", "ds_walls")
    expected = filled((3, 3), at=np.s_[0, :], value=1.0)
    np.testing.assert_array_equal(actor[0, 0, -2], expected)
    np.testing.assert_allclose(
        critic[0, -1], ref_downsize(walls[0].reshape(5, 5) * 1.0, 3), atol=1e-6
    )


# ----------------------------------------------------------------------------- downsizing


@pytest.mark.parametrize("rows,cols,w", [(10, 10, 3), (7, 11, 5), (30, 30, 9), (4, 4, 3)])
def test_downsize_matrix_equals_scipy_filters(rows, cols, w):
    rng = np.random.default_rng(rows * cols + w)
    r = downsize_matrix(rows, cols, w)
    assert r.shape == (w * w, rows * cols)
    for _ in range(3):
        m = rng.random((rows, cols))
        np.testing.assert_allclose(
            (r @ m.ravel()).reshape(w, w), ref_downsize(m, w), rtol=1e-10, atol=1e-12
        )


def test_downsize_keeps_corners_aligned():
    r = downsize_matrix(10, 10, 3)
    corner = filled(100, at=np.s_[0], value=1.0)
    out = (r @ corner).reshape(3, 3)
    assert out.argmax() == 0 and out[0, 0] > out[1, 1] > out[2, 2]


# ----------------------------------------------------------------------------- validation


@pytest.mark.parametrize("window", [1, 4, 5, 7])
def test_bad_odmtl_window_is_rejected(window):
    with pytest.raises(ValueError, match="window"):
        make_observer(make_spec(5, 6, 2), ObservationSpec("odmtl", window=window))


def test_a_window_larger_than_the_grid_is_refused_with_the_rule_that_applies():
    spec = make_spec(5, 6, 2)
    with pytest.raises(ValueError, match=r"1 < w < min\(rows, cols\) = 5 .*got w = 7"):
        make_observer(spec, ObservationSpec("odmtl", window=7))
    assert make_observer(spec, ObservationSpec("odmtl", window=7), any_window=True).window == 7
    # an expert's observer (any_window) still needs a window: w = 1 breaks only "w > 1"
    with pytest.raises(ValueError, match=r"satisfy w > 1 \(thesis 3.6.1\), got w = 1"):
        make_observer(spec, ObservationSpec("odmtl", window=1), any_window=True)


@pytest.mark.parametrize(
    "kwargs", [{"kind": "qmix"}, {"window": 4}, {"window": 0}, {"window": 3.0}, {"walls": 1}]
)
def test_bad_observation_spec_is_rejected(kwargs):
    with pytest.raises(ValueError):
        ObservationSpec(**kwargs)


def test_dmtl_ignores_window_size():
    observer = make_observer(make_spec(4, 4, 2), ObservationSpec("dmtl", window=9))
    assert observer.actor_shape == (4, 4, 4)


def test_observation_spec_round_trips():
    spec = ObservationSpec("dmtl", window=5, walls=True)
    assert ObservationSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(ValueError, match="unknown"):
        ObservationSpec.from_dict({"kind": "dmtl", "size": 3})


def test_observe_rejects_wrong_agent_count():
    observer = make_observer(make_spec(5, 5, 3), ObservationSpec("dmtl"))
    with pytest.raises(ValueError, match="pos"):
        observer.observe(make_env(make_spec(5, 5, 2), [[0, 1]]))


def test_observe_writes_into_given_buffers():
    rng = np.random.default_rng(3)
    spec = make_spec(6, 6, 2)
    env = random_env(rng, spec, b=4)
    for kind in ("cmtl", "dmtl", "odmtl"):
        observer = make_observer(spec, ObservationSpec(kind))
        actor, critic = observer.observe(env)
        out = (np.full_like(actor, np.nan), np.full_like(critic, np.nan))
        observer.observe(env, out=out)
        np.testing.assert_array_equal(out[0], actor)
        np.testing.assert_array_equal(out[1], critic)
        with pytest.raises(ValueError, match="out"):
            observer.observe(env, out=(out[0][:2], out[1]))


# ----------------------------------------------------------------------------- joint actions


def test_joint_encoding_agent_zero_is_most_significant():
    actions = np.array([[1, 3], [4, 0], [0, 0]])
    joint = encode_joint(actions, 5)
    np.testing.assert_array_equal(joint, [8, 20, 0])
    np.testing.assert_array_equal(decode_joint(joint, 5, 2), actions)
    rng = np.random.default_rng(0)
    many = rng.integers(0, 9, (50, 3))
    np.testing.assert_array_equal(decode_joint(encode_joint(many, 9), 9, 3), many)
    with pytest.raises(ValueError):
        encode_joint(np.array([[5, 0]]), 5)
    with pytest.raises(ValueError):
        decode_joint(np.array([25]), 5, 2)


def test_joint_mask_requires_every_component_valid():
    mask = np.ones((2, 2, 3), bool)
    mask[0, 0, 1] = False  # env 0: agent 0 cannot take action 1
    mask[1, 1, 2] = False  # env 1: agent 1 cannot take action 2
    jm = joint_mask(mask)
    assert jm.shape == (2, 9)
    joint = np.arange(9)
    acts = decode_joint(joint, 3, 2)
    np.testing.assert_array_equal(jm[0], acts[:, 0] != 1)
    np.testing.assert_array_equal(jm[1], acts[:, 1] != 2)


def test_num_actor_outputs():
    assert make_observer(make_spec(10, 10, 3), ObservationSpec("cmtl")).num_actor_outputs(5) == 125
    for kind in ("dmtl", "odmtl"):
        observer = make_observer(make_spec(10, 10, 3), ObservationSpec(kind))
        assert observer.num_actor_outputs(9) == 9 and not observer.joint_actions


def test_odmtl_full_critic_sees_the_dmtl_joint_maps_and_leaves_the_actor_alone():
    from workers.mdrl.env import TargetLocalizationEnv
    from workers.mdrl.spec import EnvSpec

    spec = EnvSpec(rows=8, cols=8, agents=3, walls=(0, 2))
    env = TargetLocalizationEnv(spec, 16, seed=3)
    rng = np.random.default_rng(0)
    for _ in range(4):
        keys = rng.random(env.action_mask().shape) * env.action_mask()
        env.step(keys.argmax(-1))
    reduced = make_observer(spec, ObservationSpec("odmtl", critic="reduced"))
    full = make_observer(spec, ObservationSpec("odmtl", critic="full"))
    dmtl = make_observer(spec, ObservationSpec("dmtl"))
    a_red, _ = reduced.observe(env)
    a_full, c_full = full.observe(env)
    _, c_dmtl = dmtl.observe(env)
    assert full.critic_shape == dmtl.critic_shape == (4, 8, 8)
    np.testing.assert_array_equal(a_full, a_red)
    np.testing.assert_allclose(c_full, c_dmtl, rtol=1e-6)
    with pytest.raises(ValueError, match="critic must be"):
        ObservationSpec("odmtl", critic="huge")


# ----------------------------------------------------------------------------- kept maps


@pytest.mark.parametrize(
    ("rows", "window", "readings"),
    [
        (9, 5, "last"),
        (9, 7, "mean"),
        (12, 9, "last"),  # walls windows as bits (w <= 7), padded
    ],
)
def test_odmtl_maps_kept_between_steps_equal_a_fresh_observer_and_the_reference(
    rows, window, readings
):
    """The ODMTL observer keeps its maps per env and updates them at the agents' cells after
    a step (the downsized visits in exact fixed point, the walls maps at resets): through
    resets, skipped and repeated observations, agents sharing cells and frozen envs it equals
    a fresh observer bit for bit, and the slow reference up to float32 round-off."""
    from workers.mdrl.env import TargetLocalizationEnv
    from workers.mdrl.spec import EnvSpec

    spec = EnvSpec(rows=rows, cols=rows + 1, agents=4, moves=8, walls=(1, 3), max_steps=15)
    osp = ObservationSpec("odmtl", window=window, readings=readings)
    kept = make_observer(spec, osp)
    env = TargetLocalizationEnv(spec, 24, seed=4)
    rng = np.random.default_rng(0)
    shared = 0
    for step in range(60):
        keys = rng.random(env.action_mask().shape) * env.action_mask()
        env.active[:3] = step % 9 != 4  # now and then three envs sit a step out
        env.step(keys.argmax(-1))
        env.active[:3] = True
        shared += sum(len(set(p)) < 4 for p in env.pos.tolist())
        if step % 6 == 5:
            continue  # two steps between observations
        got = kept.observe(env)
        if step % 10 == 0:
            got = kept.observe(env)  # twice without a step
        for a, b in zip(got, make_observer(spec, osp).observe(env), strict=True):
            np.testing.assert_array_equal(a, b)
        if readings == "last" and step % 10 == 1:  # the reference reads the last readings
            ref_a, ref_c = reference(spec, osp, env)
            np.testing.assert_allclose(got[0], ref_a, atol=1e-6)
            np.testing.assert_allclose(got[1], ref_c, atol=1e-6)
    assert shared and isinstance(next(iter(kept._kept.values())), _Kept)


def test_visits_that_are_not_small_integers_take_the_float_products():
    # fractional visits cannot go through the fixed-point product: the float32 one instead
    rng = np.random.default_rng(5)
    spec = make_spec(rows=7, cols=9, agents=3, walls=(0, 3))
    obs = ObservationSpec("odmtl", window=5)
    env = random_env(rng, spec, b=6)
    env.visits = env.visits * np.float32(0.37)
    actor, critic = make_observer(spec, obs).observe(env)
    ref_a, ref_c = reference(spec, obs, env)
    np.testing.assert_allclose(actor, ref_a, atol=1e-5)
    np.testing.assert_allclose(critic, ref_c, atol=1e-5)
