"""Physics and invariants of the batched target-localization environment."""

from collections import deque

import numpy as np
import pytest

from workers.mdrl.env import UNREACHABLE, TargetLocalizationEnv
from workers.mdrl.spec import MOVES, MOVES_8, EnvSpec, IntensitySpec


def random_actions(env, rng):
    """A valid random action per agent (uniform over the mask)."""
    keys = rng.random(env.action_mask().shape) * env.action_mask()
    return keys.argmax(-1)


def place(env, b, target, agents):
    """Put env b into a hand-made layout (no walls) and recompute what reset would."""
    env.walls[b] = False
    env._next_stale[b] = True
    env.target[b] = target
    env.dist[b] = env._free_dist[target]
    env.mean_reading[b] = env.expected_counts(
        np.array([target]), env.walls[b : b + 1], env.intensity[b : b + 1]
    )[0]
    env.pos[b] = agents
    env.history[b] = np.asarray(agents)[None, :]
    env.t[b] = env.idle_streak[b] = env.cost[b] = 0
    env._update_masks(np.array([b]))


def test_expected_reading_follows_inverse_square_and_intensity():
    spec = EnvSpec(rows=10, cols=10, agents=1)
    env = TargetLocalizationEnv(spec, 2, seed=0)
    env.intensity[:] = [1e9, 2.5e8]
    place(env, 0, 0, [99])
    place(env, 1, 0, [99])
    m = env.mean_reading
    # Cells (0,1), (0,2), (0,4): 100 m, 200 m, 400 m from the source at (0,0).
    assert m[0, 1] / m[0, 2] == pytest.approx(4.0)
    assert m[0, 1] / m[0, 4] == pytest.approx(16.0)
    assert m[0, 5] / m[1, 5] == pytest.approx(4.0)  # proportional to I
    # 1e9 photons/min, 200 cm^2, 1 min, 100 m: I * A / (4 pi d^2)
    assert m[0, 1] == pytest.approx(1e9 * 200 / (4 * np.pi * 1e4**2))


def test_readings_are_poisson_with_the_expected_mean():
    spec = EnvSpec(rows=10, cols=10, agents=1)
    env = TargetLocalizationEnv(spec, 4000, seed=1)
    env.intensity[:] = 1e9
    for b in range(env.num_envs):
        place(env, b, 0, [44])
    env.step(np.zeros((env.num_envs, 1), dtype=np.int64))  # idle: read again at cell 44
    lam = env.mean_reading[0, 44]
    r = env.readings[:, 44]
    assert np.all(r == np.round(r))
    # mean within 5 standard errors, variance ~ mean (Poisson)
    assert abs(r.mean() - lam) < 5 * np.sqrt(lam / len(r))
    assert r.var() == pytest.approx(lam, rel=0.15)


def test_expected_readings_option_is_noise_free():
    spec = EnvSpec(rows=10, cols=10, agents=1, readings="expected")
    env = TargetLocalizationEnv(spec, 8, seed=1)
    env.step(np.zeros((8, 1), dtype=np.int64))
    rows = np.arange(8)
    cells = env.pos[:, 0]
    assert np.allclose(env.readings[rows, cells], env.mean_reading[rows, cells], rtol=1e-6)
    with pytest.raises(ValueError, match="readings must be"):
        EnvSpec(readings="gaussian")


def test_walls_attenuate_readings_and_block_moves():
    spec = EnvSpec(rows=10, cols=10, agents=1, walls=(1, 1))
    env = TargetLocalizationEnv(spec, 1, seed=0)
    walls = np.zeros((1, 100), dtype=bool)
    walls[0, [r * 10 + 5 for r in range(6)]] = True  # a wall down from the top in column 5
    target = np.array([2 * 10 + 2])  # (2, 2), west of the wall
    free = env.expected_counts(target, np.zeros_like(walls), np.array([1e9]))[0]
    blocked = env.expected_counts(target, walls, np.array([1e9]))[0]
    behind, beside = 2 * 10 + 8, 8 * 10 + 2  # (2, 8) behind the wall; (8, 2) same side, not behind
    slab = np.exp(-spec.wall_mu_per_cm * spec.wall_thickness_cm)  # perpendicular crossing
    assert blocked[behind] == pytest.approx(free[behind] * slab)
    assert blocked[beside] == free[beside]
    assert blocked[9 * 10 + 7] == free[9 * 10 + 7]  # the line passes below the wall end
    valid = env._valid_moves(walls)[0]
    assert not valid[2 * 10 + 4, 4]  # (2,4) -> right into the wall at (2,5)
    assert valid[7 * 10 + 4, 4]  # below the wall the way is open


def test_diagonal_moves_do_not_cut_wall_corners():
    spec = EnvSpec(rows=6, cols=6, agents=1, moves=8, walls=(1, 1))
    env = TargetLocalizationEnv(spec, 1, seed=0)
    walls = np.zeros((1, 36), dtype=bool)
    walls[0, [0 * 6 + 3, 1 * 6 + 3]] = True  # column 3, rows 0-1
    valid = env._valid_moves(walls)[0]
    se = next(a for a, d in enumerate(MOVES_8) if tuple(d) == (1, 1))
    ne = next(a for a, d in enumerate(MOVES_8) if tuple(d) == (-1, 1))
    assert not valid[1 * 6 + 2, se]  # (1,2) -> (2,3) would brush the wall cell (1,3)
    assert not valid[2 * 6 + 2, ne]  # (2,2) -> (1,3) is a wall
    assert valid[2 * 6 + 2, se]  # open corner


def test_bfs_distances_go_around_walls_and_agree_with_moves():
    spec = EnvSpec(rows=10, cols=10, agents=2, walls=(3, 3), moves=8)
    env = TargetLocalizationEnv(spec, 64, seed=3)
    for b in range(env.num_envs):
        d = env.dist[b]
        reach = d < UNREACHABLE
        assert d[env.target[b]] == 0
        assert not reach[env.walls[b]].any()
        # every reachable non-target cell has a move to a cell one step closer; none to two closer
        for c in np.flatnonzero(reach):
            nxt = env.next_cell[b, c]
            nd = d[nxt[nxt >= 0]]
            if c != env.target[b]:
                assert nd.min() == d[c] - 1
            assert nd.min() >= d[c] - 1


def test_starts_are_distinct_reachable_and_not_on_the_target():
    spec = EnvSpec(rows=6, cols=6, agents=5, walls=(0, 3))
    env = TargetLocalizationEnv(spec, 500, seed=4)
    for b in range(env.num_envs):
        p = env.pos[b]
        assert len(set(p.tolist())) == 5
        assert env.target[b] not in p
        assert (env.dist[b, p] < UNREACHABLE).all()
        assert not env.walls[b, p].any()


def test_masks_keep_agents_on_the_grid_and_invalid_actions_raise():
    spec = EnvSpec(rows=5, cols=5, agents=1)
    env = TargetLocalizationEnv(spec, 1, seed=0)
    place(env, 0, 24, [0])  # top-left corner
    mask = env.action_mask()[0, 0]
    assert mask.tolist() == [True, False, True, False, True]  # idle, down, right
    with pytest.raises(ValueError, match="invalid action 1 for agent 0 in env 0"):
        env.step(np.array([[1]]))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((1, 2), dtype=np.int64))


def test_idle_is_masked_after_three_all_idle_steps():
    spec = EnvSpec(rows=5, cols=5, agents=2)
    env = TargetLocalizationEnv(spec, 1, seed=0)
    place(env, 0, 24, [0, 12])
    idle = np.zeros((1, 2), dtype=np.int64)
    for _ in range(3):
        assert env.action_mask()[0, :, 0].all()
        env.step(idle)
    assert not env.action_mask()[0, :, 0].any()
    env.step(np.array([[2, 1]]))  # everyone must move; then idle is allowed again
    assert env.action_mask()[0, :, 0].all()


def test_shaped_reward_eq5_and_termination_on_the_target():
    spec = EnvSpec(rows=5, cols=5, agents=2, reward="shaped")
    env = TargetLocalizationEnv(spec, 1, seed=0)
    place(env, 0, 2, [0, 24])  # target (0,2); agents at (0,0) and (4,4)
    r = env.step(np.array([[4, 0]]))  # closest agent moves right: closer, 1 mover
    assert r.reward[0] == 1 - 1 and not r.terminated[0]
    r = env.step(np.array([[0, 1]]))  # far agent moves up: min distance unchanged
    assert r.reward[0] == -1 - 1
    r = env.step(np.array([[4, 0]]))  # reaches the target
    assert r.terminated[0] and r.reward[0] == 0
    assert r.episode.found.tolist() == [True]
    assert r.episode.length.tolist() == [3] and r.episode.cost.tolist() == [3]
    assert env.t[0] == 0  # auto-reset


def test_sparse_reward_eq9():
    spec = EnvSpec(rows=5, cols=5, agents=2, reward="sparse", sparse_bonus=50)
    env = TargetLocalizationEnv(spec, 1, seed=0)
    place(env, 0, 2, [1, 24])
    assert env.step(np.array([[0, 1]])).reward[0] == -1
    assert env.step(np.array([[4, 1]])).reward[0] == -2 + 50


def test_truncation_at_max_steps_and_frozen_envs_without_autoreset():
    spec = EnvSpec(rows=5, cols=5, agents=1, max_steps=4)
    env = TargetLocalizationEnv(spec, 2, seed=0, autoreset=False)
    place(env, 0, 24, [0])
    place(env, 1, 1, [0])
    r = env.step(np.array([[2], [4]]))  # env 1 finds its target at once
    assert r.terminated.tolist() == [False, True]
    frozen = env.pos[1].copy()
    for k in range(3):
        r = env.step(np.array([[2 if k % 2 else 1], [1]]))  # env 1's action is ignored
    assert r.truncated.tolist() == [True, False]
    assert env.done and (env.pos[1] == frozen).all()


def test_same_seed_same_episodes_whatever_the_actions():
    spec = EnvSpec(
        rows=8, cols=8, agents=3, walls=(0, 2), intensity=IntensitySpec.uniform(1e8, 1e9)
    )
    a = TargetLocalizationEnv(spec, 16, seed=7, autoreset=False)
    b = TargetLocalizationEnv(spec, 16, seed=7, autoreset=False)
    assert (a.target == b.target).all() and (a.pos == b.pos).all() and (a.walls == b.walls).all()
    assert (a.intensity == b.intensity).all()
    rng = np.random.default_rng(0)
    a.step(random_actions(a, rng))  # different histories, same layouts on the next reset
    a.reset()
    b.reset()
    assert (a.target == b.target).all() and (a.pos == b.pos).all()


def test_state_dict_restores_an_identical_continuation():
    spec = EnvSpec(rows=6, cols=6, agents=2, walls=(0, 2), moves=8)
    env = TargetLocalizationEnv(spec, 8, seed=5)
    rng = np.random.default_rng(1)
    for _ in range(7):
        env.step(random_actions(env, rng))
    arrays, extras = env.state_dict()
    assert "next_cell" not in arrays  # derived from the walls: not stored
    twin = TargetLocalizationEnv(spec, 8, seed=999)
    twin.load_state_dict({**arrays, "next_cell": np.zeros(1)}, extras)  # an older checkpoint
    np.testing.assert_array_equal(twin.next_cell, env.next_cell)
    for _ in range(30):
        act = random_actions(env, rng)
        ra, rb = env.step(act), twin.step(act)
        assert (ra.reward == rb.reward).all()
        assert (env.readings == twin.readings).all() and (env.pos == twin.pos).all()


def test_spec_validation_and_json_round_trip():
    spec = EnvSpec(
        rows=12, cols=9, agents=4, walls=(1, 3), moves=8, intensity=IntensitySpec.choice([1e8, 1e9])
    )
    assert EnvSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(ValueError, match="moves must be 4 or 8"):
        EnvSpec(moves=6)
    with pytest.raises(ValueError, match="do not fit"):
        EnvSpec(rows=2, cols=2, agents=4)
    with pytest.raises(ValueError, match="intensity"):
        IntensitySpec.parse("lots")
    assert IntensitySpec.parse("1e8:1e9") == IntensitySpec.uniform(1e8, 1e9)


def test_transmission_of_many_layouts_equals_each_layout_alone():
    # at reset the walls are evaluated per (env, wall line) pair; alone, line by line
    spec = EnvSpec(rows=12, cols=9, agents=2, moves=8, walls=(1, 3))
    env = TargetLocalizationEnv(spec, 24, seed=6)
    together = env.expected_counts(env.target, env.walls, env.intensity)
    assert (together < env._free_gain[env.target] * env.intensity[:, None]).any()  # walls bite
    for b in range(env.num_envs):
        alone = env.expected_counts(
            env.target[b : b + 1], env.walls[b : b + 1], env.intensity[b : b + 1]
        )[0]
        np.testing.assert_array_equal(together[b], alone)


def reference_table(spec, walls):
    """(C, A) move table of one layout, cell by cell from the rules (module docstring)."""
    m, n = spec.rows, spec.cols
    grid = walls.reshape(m, n)
    free = lambda r, c: 0 <= r < m and 0 <= c < n and not grid[r, c]  # noqa: E731
    table = np.full((m * n, spec.num_actions), -1)
    for cell in range(m * n):
        r, c = divmod(cell, n)
        for a, (dr, dc) in enumerate(MOVES[spec.moves]):
            corners = free(r + dr, c) and free(r, c + dc) if dr and dc else True
            if free(r + dr, c + dc) and corners:
                table[cell, a] = (r + dr) * n + c + dc
    return table


def reference_bfs(table, target):
    """BFS steps to ``target`` over a move table, one cell at a time (moves are symmetric)."""
    dist = np.full(len(table), UNREACHABLE)
    dist[target] = 0
    queue = deque([target])
    while queue:
        cell = queue.popleft()
        for nxt in table[cell]:
            if nxt >= 0 and dist[nxt] == UNREACHABLE:
                dist[nxt] = dist[cell] + 1
                queue.append(nxt)
    return dist


@pytest.mark.parametrize(
    ("rows", "cols", "moves", "walls"),
    [
        (12, 9, 4, (1, 3)),
        (12, 9, 8, (1, 3)),
        (9, 30, 8, (3, 3)),
        (6, 70, 8, (2, 4)),
    ],
)
def test_moves_and_distances_equal_a_cell_by_cell_reference(rows, cols, moves, walls):
    # up to 64 columns the BFS runs on bit rows, beyond on bool grids; both against a queue
    spec = EnvSpec(rows=rows, cols=cols, agents=2, moves=moves, walls=walls)
    env = TargetLocalizationEnv(spec, 12, seed=8)
    rng = np.random.default_rng(0)
    for _ in range(3):
        for b in range(env.num_envs):
            table = reference_table(spec, env.walls[b])
            np.testing.assert_array_equal(env.next_cell[b], table)
            np.testing.assert_array_equal(env.dist[b], reference_bfs(table, env.target[b]))
            np.testing.assert_array_equal(env.action_mask()[b], table[env.pos[b]] >= 0)
        for _ in range(40):  # on to other layouts (resets rebuild next_cell on demand)
            env.step(random_actions(env, rng))
    few = env._bfs(env.target[:3], env.walls[:3])
    np.testing.assert_array_equal(few, env.dist[:3])
    assert (env.dist >= UNREACHABLE).any() and (env.dist[env.dist < UNREACHABLE] > 8).any()


def test_wall_layouts_equal_a_wall_by_wall_reference():
    # the same draws as draw_walls, the cells placed one wall at a time
    spec = EnvSpec(rows=9, cols=13, agents=2, walls=(0, 4))
    got = TargetLocalizationEnv.draw_walls(spec, np.random.default_rng(3), 200)
    rng = np.random.default_rng(3)
    m, n, (lo, hi) = spec.rows, spec.cols, spec.walls
    want = np.zeros((200, m, n), dtype=bool)
    count = rng.integers(lo, hi + 1, size=200)
    taken = np.zeros((200, 4, max(m, n)), dtype=bool)
    for k in range(hi):
        side = rng.integers(0, 4, size=200)
        along = np.where(side < 2, n, m)
        place = rng.integers(1, along - 1)
        again = taken[np.arange(200), side, place]
        while again.any():
            side[again] = rng.integers(0, 4, size=int(again.sum()))
            along = np.where(side < 2, n, m)
            place[again] = rng.integers(1, along[again] - 1)
            again = taken[np.arange(200), side, place]
        taken[np.arange(200), side, place] = True
        span = np.where(side < 2, m, n)
        bounds = [spec.wall_length_range(int(s)) for s in span]
        length = rng.integers([b[0] for b in bounds], [b[1] + 1 for b in bounds])
        for b in np.flatnonzero(k < count):
            for j in range(length[b]):
                r, c = [(j, place[b]), (m - 1 - j, place[b]), (place[b], j), (place[b], n - 1 - j)][
                    side[b]
                ]
                want[b, r, c] = True
    np.testing.assert_array_equal(got, want.reshape(200, -1))
    assert (want.sum((1, 2)) > 0).any() and (count == 0).any()


def reference_transmission(env, target, walls):
    """Beer-Lambert factor per detector: each wall slab crossed adds 1 / cos(theta), cell line
    by cell line, the two orientations summed apart (the slab of a wall: its centre line, from
    its side to the far edge of its last cell)."""
    spec = env.spec
    m, n = spec.rows, spec.cols
    cy, cx = spec.cell_size_m
    grid = walls.reshape(m, n)
    qy, qx = env.centre_m[target]
    out = np.empty(m * n)
    for cell, (py, px) in enumerate(env.centre_m):
        length = np.hypot(py - qy, px - qx)
        slant, across = 0.0, 0.0
        for col in range(n):  # slabs on column centre lines: walls from the top or bottom
            top = int(np.cumprod(grid[:, col]).sum())
            bottom = int(np.cumprod(grid[::-1, col]).sum())
            aw = (col + 0.5) * cx
            if (px - aw) * (qx - aw) < 0:
                y = py + (px - aw) / ((px - aw) - (qx - aw)) * (qy - py)
                if (top and y <= top * cy) or (bottom and y >= (m - bottom) * cy):
                    slant += length / abs(px - qx)
        for row in range(m):  # slabs on row centre lines: walls from the left or right
            left = int(np.cumprod(grid[row]).sum())
            right = int(np.cumprod(grid[row, ::-1]).sum())
            aw = (row + 0.5) * cy
            if (py - aw) * (qy - aw) < 0:
                x = px + (py - aw) / ((py - aw) - (qy - aw)) * (qx - px)
                if (left and x <= left * cx) or (right and x >= (n - right) * cx):
                    across += length / abs(py - qy)
        out[cell] = np.exp(-spec.wall_mu_per_cm * spec.wall_thickness_cm * (slant + across))
    return out


@pytest.mark.parametrize(("rows", "cols", "walls"), [(12, 9, (1, 3)), (12, 12, (10, 10))])
def test_transmission_equals_a_slab_by_slab_reference(rows, cols, walls):
    # 10 walls: lines that cross 4 or more slabs of one orientation (sums of 4+ equal terms)
    spec = EnvSpec(rows=rows, cols=cols, agents=2, moves=8, walls=walls)
    env = TargetLocalizationEnv(spec, 6, seed=0)
    got = env._transmission(env.target, env.walls)
    for b in range(env.num_envs):
        want = reference_transmission(env, env.target[b], env.walls[b])
        np.testing.assert_array_equal(got[b], want)
    assert (got < 1).any()
