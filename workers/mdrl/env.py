"""Batched multi-agent target localization: one object steps B environments as arrays.

Thesis Ch. 3.2/3.7.1 (Poisson readings, Eq. 6; team rewards Eq. 5/8 and Eq. 9) and Ch. 4.3-4.4
(walls from the sides, 8 directions + idle, invalid-move masks, the all-idle rule). What is fixed
within an episode (BFS distance map, expected-reading map, the move table with walls) is computed
once at reset, so a step is a handful of gathers over (B, N) arrays.

Walls (ours where the thesis is silent): a wall starts at one side of the area, at a cell drawn
away from the corners, and runs perpendicular to that side for a random length of at most
span - 2 cells; no two walls leave the same side on the same line (they would merge), so an
episode has exactly the drawn number of walls (Ch. 4: "the number of walls is fixed").
Wall cells cannot be entered; a diagonal move may not cut the corner of a wall cell. Walls can
wall off pockets: the target is drawn among free cells, and agents start only in cells from
which the target is reachable (the target of Ch. 3/4 is always reachable).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from .spec import MOVES, EnvSpec

#: BFS distance of cells that cannot reach the target (walls, walled-off pockets).
UNREACHABLE = 1_000_000
#: Positions remembered per env for ``past_pos`` (ODMTL windows need (w - 1) / 2 steps back).
HISTORY = 16


@dataclass
class EpisodeStats:
    """Episodes that ended in one step: which envs, and how they ended."""

    index: np.ndarray  # (k,) env indices
    found: np.ndarray  # (k,) bool: an agent stepped on the target
    length: np.ndarray  # (k,) steps taken (localization time)
    cost: np.ndarray  # (k,) moving actions taken by the whole team


@dataclass
class StepResult:
    reward: np.ndarray  # float32 (B,) team reward (shared by all agents)
    terminated: np.ndarray  # bool (B,) target found in this step
    truncated: np.ndarray  # bool (B,) step limit reached without finding it
    episode: EpisodeStats | None


class TargetLocalizationEnv:
    """B target-localization episodes stepped together. See ``docs/mdrl-core.md`` for the state."""

    def __init__(
        self, spec: EnvSpec, num_envs: int = 1, seed: int | None = None, autoreset: bool = True
    ) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.spec = spec
        self.num_envs = num_envs
        self.autoreset = autoreset
        B, N, C, A = num_envs, spec.agents, spec.num_cells, spec.num_actions
        m, n = spec.rows, spec.cols
        self.moves = MOVES[spec.moves]

        # Static geometry, shared by all episodes.
        self.cell_row = np.repeat(np.arange(m), n)
        self.cell_col = np.tile(np.arange(n), m)
        cy, cx = spec.cell_size_m
        self.centre_m = np.stack([(self.cell_row + 0.5) * cy, (self.cell_col + 0.5) * cx], axis=1)
        nr = self.cell_row[:, None] + self.moves[None, :, 0]
        nc = self.cell_col[:, None] + self.moves[None, :, 1]
        inside = (nr >= 0) & (nr < m) & (nc >= 0) & (nc < n)
        self._free_next = np.where(inside, nr * n + nc, -1)  # (C, A) move table without walls
        # A spec without walls gives every env this table: steps and masks read the small shared
        # table instead of gathering from next_cell (B * C * A entries, far beyond the caches).
        self._one_table = spec.walls[1] == 0
        diff = (
            np.abs(self.cell_row[:, None] - self.cell_row[None]),
            np.abs(self.cell_col[:, None] - self.cell_col[None]),
        )
        # Wall-free BFS distances have a closed form: Manhattan (4 moves) or Chebyshev (8 moves).
        self._free_dist = (diff[0] + diff[1] if spec.moves == 4 else np.maximum(*diff)).astype(
            np.int32
        )
        d2_cm2 = ((self.centre_m[:, None, :] - self.centre_m[None, :, :]) ** 2).sum(-1) * 1e4
        d2_cm2 = np.maximum(d2_cm2, (min(cy, cx) * 100 / 2) ** 2)
        # Expected count per photon/min without walls (Eq. 6): dwell * area / (4 pi d^2).
        self._free_gain = spec.dwell_min * spec.detector_area_cm2 / (4 * np.pi * d2_cm2)

        # Per-env state (documented in docs/mdrl-core.md).
        self.pos = np.zeros((B, N), dtype=np.int64)
        self.target = np.zeros(B, dtype=np.int64)
        self.walls = np.zeros((B, C), dtype=bool)
        self.dist = np.zeros((B, C), dtype=np.int32)
        self.mean_reading = np.zeros((B, C), dtype=np.float64)
        self.readings = np.zeros((B, C), dtype=np.float32)
        self.reading_sum = np.zeros((B, C), dtype=np.float64)
        self.visits = np.zeros((B, C), dtype=np.float32)
        self.episode_id = np.zeros(B, dtype=np.int64)
        self.t = np.zeros(B, dtype=np.int64)
        self.idle_streak = np.zeros(B, dtype=np.int64)
        self.intensity = np.zeros(B, dtype=np.float64)
        self.cost = np.zeros(B, dtype=np.int64)
        self.next_cell = np.zeros((B, C, A), dtype=np.int64)
        self.active = np.ones(B, dtype=bool)  # False: episode over and frozen (autoreset=False)
        self.history = np.zeros((B, HISTORY, N), dtype=np.int64)
        self._mask = np.zeros((B, N, A), dtype=bool)
        self._rows = np.arange(B)
        self._agent_offsets = np.arange(B * N).reshape(B, N) * A  # flat (b, i, 0) in (B, N, A)
        self.seed(seed)
        self.reset()

    # ------------------------------------------------------------------ seeding and state
    def seed(self, seed: int | None) -> None:
        """Two streams: layouts (so policies see the same episodes) and reading noise."""
        layout, noise = np.random.SeedSequence(seed).spawn(2)
        self.layout_rng = np.random.Generator(np.random.PCG64(layout))
        self.noise_rng = np.random.Generator(np.random.PCG64(noise))

    _STATE = (
        "pos target walls dist mean_reading readings reading_sum visits episode_id t idle_streak "
        "intensity cost next_cell active history _mask"
    ).split()

    def state_dict(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """(arrays, JSON-able extras) that restore this env exactly, mid-episode included."""
        arrays = {name.lstrip("_"): getattr(self, name).copy() for name in self._STATE}
        extras = {
            "spec": self.spec.to_dict(),
            "num_envs": self.num_envs,
            "autoreset": self.autoreset,
            "layout_rng": self.layout_rng.bit_generator.state,
            "noise_rng": self.noise_rng.bit_generator.state,
        }
        return arrays, extras

    def load_state_dict(self, arrays: dict[str, np.ndarray], extras: dict[str, Any]) -> None:
        if EnvSpec.from_dict(extras["spec"]) != self.spec or extras["num_envs"] != self.num_envs:
            raise ValueError("saved environment state is for another spec or number of envs")
        for name in self._STATE:
            current = getattr(self, name)
            value = np.asarray(arrays[name.lstrip("_")])
            if value.shape != current.shape:
                raise ValueError(
                    f"saved env array {name} has shape {value.shape}, expected {current.shape}"
                )
            current[...] = value
        self.layout_rng.bit_generator.state = extras["layout_rng"]
        self.noise_rng.bit_generator.state = extras["noise_rng"]

    # ------------------------------------------------------------------ episodes
    def reset(self, seed: int | None = None) -> None:
        """Start new episodes in all B environments."""
        if seed is not None:
            self.seed(seed)
        self._reset_rows(self._rows)

    def _reset_rows(self, rows: np.ndarray) -> None:
        spec, rng = self.spec, self.layout_rng
        R, C, N = len(rows), spec.num_cells, spec.agents
        walls = self.draw_walls(spec, rng, R)
        self.walls[rows] = walls
        next_cell = self._move_table(walls)
        self.next_cell[rows] = next_cell

        # Target among free cells; agents at distinct cells that can reach it.
        keys = rng.random((R, C))
        keys[walls] = 2.0
        target = keys.argmin(axis=1)
        dist = self._bfs(target, walls, next_cell)
        reachable = dist < UNREACHABLE
        short = reachable.sum(1) < N + 1
        if short.any():  # a pocket too small to hold the team: draw those layouts again
            self._reset_rows(rows[~short]) if (~short).any() else None
            self._reset_rows(rows[short])
            return
        keys = rng.random((R, C))
        keys[~reachable] = 2.0
        keys[np.arange(R), target] = 2.0
        # the N smallest keys in increasing order (= argsort(keys)[:, :N], without a full sort)
        start = np.argpartition(keys, N - 1, axis=1)[:, :N]  # N < C (spec: N + 1 <= C)
        start = np.take_along_axis(start, np.argsort(np.take_along_axis(keys, start, 1), 1), 1)

        self.target[rows] = target
        self.dist[rows] = dist
        self.intensity[rows] = intensity = spec.intensity.sample(rng, R)
        self.mean_reading[rows] = self.expected_counts(target, walls, intensity)
        self.pos[rows] = start
        self.history[rows] = start[:, None, :]
        self.t[rows] = 0
        self.idle_streak[rows] = 0
        self.cost[rows] = 0
        self.active[rows] = True
        self.visits[rows] = 0
        self.readings[rows] = 0
        self.reading_sum[rows] = 0
        self.episode_id[rows] += 1
        self._take_readings(rows, start)
        self._mask[rows] = self._masks(rows)

    @staticmethod
    def draw_walls(spec: EnvSpec, rng: np.random.Generator, R: int) -> np.ndarray:
        """(R, C) wall maps: each wall leaves a side at a non-corner cell, perpendicular to it.
        Public (a static method) so the walls CAE (``cae.py``) trains on the env's own layouts."""
        m, n = spec.rows, spec.cols
        walls = np.zeros((R, m, n), dtype=bool)
        lo, hi = spec.walls
        if hi == 0:
            return walls.reshape(R, -1)
        count = rng.integers(lo, hi + 1, size=R)
        taken = np.zeros((R, 4, max(m, n)), dtype=bool)  # (side, place) already holding a wall
        for k in range(hi):
            side = rng.integers(0, 4, size=R)  # 0 top, 1 bottom, 2 left, 3 right
            vertical = side < 2
            along = np.where(vertical, n, m)  # cells along the side
            span = np.where(vertical, m, n)  # how far a wall can reach
            place = rng.integers(1, along - 1)
            # Two walls on one line of one side would merge: draw again so the count is exact.
            again = taken[np.arange(R), side, place]
            while again.any():
                side[again] = rng.integers(0, 4, size=int(again.sum()))
                vertical, along, span = side < 2, np.where(side < 2, n, m), np.where(side < 2, m, n)
                place[again] = rng.integers(1, along[again] - 1)
                again = taken[np.arange(R), side, place]
            taken[np.arange(R), side, place] = True
            lmin = np.array([spec.wall_length_range(int(s))[0] for s in span])
            lmax = np.array([spec.wall_length_range(int(s))[1] for s in span])
            length = rng.integers(lmin, lmax + 1)
            on = k < count
            r = np.arange(m)[None, :, None]
            c = np.arange(n)[None, None, :]
            place_, length_ = place[:, None, None], length[:, None, None]
            side_ = side[:, None, None]
            cells = (
                ((side_ == 0) & (c == place_) & (r < length_))
                | ((side_ == 1) & (c == place_) & (r >= m - length_))
                | ((side_ == 2) & (r == place_) & (c < length_))
                | ((side_ == 3) & (r == place_) & (c >= n - length_))
            )
            walls |= cells & on[:, None, None]
        return walls.reshape(R, -1)

    def _move_table(self, walls: np.ndarray) -> np.ndarray:
        """(R, C, A) destination of every move; -1 off the grid, into a wall or cutting a corner."""
        R = len(walls)
        table = np.broadcast_to(self._free_next, (R, *self._free_next.shape)).copy()
        if not walls.any():
            return table
        m, n = self.spec.rows, self.spec.cols
        free = np.zeros((R, m + 2, n + 2), dtype=bool)  # a border of walls around the grid
        free[:, 1:-1, 1:-1] = ~walls.reshape(R, m, n)
        grid = table.reshape(R, m, n, -1)
        for a, (dr, dc) in enumerate(self.moves):
            ok = free[:, 1 + dr : m + 1 + dr, 1 + dc : n + 1 + dc].copy()  # destination free
            if dr and dc:  # a diagonal needs both orthogonal neighbours free (no corner cutting)
                ok &= free[:, 1 + dr : m + 1 + dr, 1 : n + 1]
                ok &= free[:, 1 : m + 1, 1 + dc : n + 1 + dc]
            grid[:, :, :, a][~ok] = -1
        return table

    #: Below this many layouts a graph search per layout beats the level-by-level grid search.
    _GRAPH_BFS_BELOW = 12

    def _bfs(self, target: np.ndarray, walls: np.ndarray, next_cell: np.ndarray) -> np.ndarray:
        """(R, C) BFS steps to the target (moves are symmetric, so search from the target).

        Without walls: the closed form. A few layouts (a typical reset): scipy's search on the
        graph of ``next_cell``. Many: level by level on the padded grid, where a cell joins the
        next level if a move from the current level reaches it, i.e. it is free and (for a
        diagonal) both orthogonal cells beside the move are free, as in ``_move_table``. The
        grid search costs ~45 levels of array passes whatever the number of layouts, the graph
        search a fixed cost per layout.
        """
        R, C = walls.shape
        dist = self._free_dist[target].copy()
        hard = np.flatnonzero(walls.any(axis=1))
        if not len(hard):
            return dist
        if len(hard) < self._GRAPH_BFS_BELOW:
            dist[hard] = _graph_bfs(target[hard], next_cell[hard])
            return dist
        m, n, k = self.spec.rows, self.spec.cols, len(hard)
        free = np.zeros((k, m + 2, n + 2), dtype=bool)  # a border of walls around the grid
        inner = free[:, 1:-1, 1:-1]
        inner[...] = ~walls[hard].reshape(k, m, n)
        straight, diagonal = [], []
        for dr, dc in self.moves[1:]:
            shift = (slice(None), slice(1 - dr, m + 1 - dr), slice(1 - dc, n + 1 - dc))
            if dr and dc:  # a diagonal does not cut a wall corner
                ok = free[:, 1 : m + 1, 1 - dc : n + 1 - dc]
                ok = ok & free[:, 1 - dr : m + 1 - dr, 1 : n + 1]
                diagonal.append((shift, ok))
            else:
                straight.append(shift)
        sub = np.full((k, m, n), UNREACHABLE, dtype=np.int32)
        frontier = np.zeros((k, m + 2, n + 2), dtype=bool)
        tr, tc = np.divmod(target[hard], n)
        at = np.arange(k)
        frontier[at, tr + 1, tc + 1] = True
        sub[at, tr, tc] = 0
        unseen = inner.copy()  # free cells not reached yet (the destination-free condition)
        unseen[at, tr, tc] = False
        reached = np.empty((k, m, n), dtype=bool)
        step = np.empty((k, m, n), dtype=bool)
        d = 0
        while True:
            d += 1
            np.logical_or(frontier[straight[0]], frontier[straight[1]], out=reached)
            for shift in straight[2:]:
                reached |= frontier[shift]
            for shift, ok in diagonal:
                np.logical_and(frontier[shift], ok, out=step)
                reached |= step
            reached &= unseen
            if not reached.any():
                break
            unseen ^= reached
            np.copyto(sub, d, where=reached)
            frontier[:, 1:-1, 1:-1] = reached
        dist[hard] = sub.reshape(k, C)
        return dist

    def expected_counts(
        self, target: np.ndarray, walls: np.ndarray, intensity: np.ndarray
    ) -> np.ndarray:
        """(R, C) mean reading at every cell for sources at ``target`` (Eq. 6 x wall transmission).

        Public so model-based baselines can evaluate hypothetical targets with the same physics.
        """
        mean = intensity[:, None] * self._free_gain[target]
        if not walls.any():
            return mean
        return mean * self._transmission(target, walls)

    def _transmission(self, target: np.ndarray, walls: np.ndarray) -> np.ndarray:
        """Beer-Lambert exp(-mu t / cos(theta)) per wall crossed by the detector-source line.

        A wall is the run of wall cells that leaves a side; its slab lies on the centre line of
        those cells, from the side to the far edge of its last cell.
        """
        spec = self.spec
        m, n = spec.rows, spec.cols
        cy, cx = spec.cell_size_m
        R = len(target)
        grid = walls.reshape(R, m, n)
        py, px = self.centre_m[None, :, 0], self.centre_m[None, :, 1]  # detectors (1, C)
        qy, qx = (
            self.centre_m[target, 0][:, None],
            self.centre_m[target, 1][:, None],
        )  # sources (R, 1)
        length = np.hypot(py - qy, px - qx)
        top = np.cumprod(grid, axis=1).sum(1)  # (R, n) run down from the top of each column
        bottom = np.cumprod(grid[:, ::-1], axis=1).sum(1)
        left = np.cumprod(grid, axis=2).sum(2)  # (R, m) run in from the left of each row
        right = np.cumprod(grid[:, :, ::-1], axis=2).sum(2)
        slant = _slab_slant(px, qx, py, qy, length, top, bottom, cx, cy, m)
        slant += _slab_slant(py, qy, px, qx, length, left, right, cy, cx, n)
        return np.exp(-spec.wall_mu_per_cm * spec.wall_thickness_cm * slant)

    # ------------------------------------------------------------------ stepping
    def action_mask(self) -> np.ndarray:
        """bool (B, N, A): valid actions now (a view; do not modify)."""
        return self._mask

    def _masks(self, rows: np.ndarray) -> np.ndarray:
        C = self.spec.num_cells
        if self._one_table:
            mask = self._free_next[self.pos[rows]] >= 0
        else:
            flat = self.next_cell.reshape(-1, self.spec.num_actions)
            mask = flat[rows[:, None] * C + self.pos[rows]] >= 0
        mask[:, :, 0] &= (self.idle_streak[rows] < self.spec.idle_limit)[:, None]
        return mask

    def past_pos(self, k: int) -> np.ndarray:
        """(B, N) positions k steps ago, clamped to the episode start (ODMTL window centres)."""
        if not 0 <= k < HISTORY:
            raise ValueError(f"past_pos keeps {HISTORY} steps, asked for {k}")
        slot = np.maximum(self.t - k, 0) % HISTORY
        return self.history[self._rows, slot]

    def _take_readings(self, rows: np.ndarray, cells: np.ndarray) -> None:
        """Poisson readings (Eq. 6) at ``cells`` (R, N): last reading per cell, the sum of all
        readings per cell (with ``visits``, the sufficient statistic of the Poisson likelihood)
        and visit counts."""
        C = self.spec.num_cells
        flat = rows[:, None] * C + cells
        lam = self.mean_reading.reshape(-1)[flat]
        noisy = self.spec.readings == "poisson"
        taken = self.noise_rng.poisson(lam) if noisy else lam
        self.readings.reshape(-1)[flat] = taken
        visits = self.visits.reshape(-1)
        total = self.reading_sum.reshape(-1)
        for i in range(flat.shape[1]):  # one agent at a time: indices unique, so += counts all
            visits[flat[:, i]] += 1.0
            total[flat[:, i]] += taken[:, i]

    def step(self, actions: np.ndarray) -> StepResult:
        """Apply one joint action per env; returns team rewards (Eq. 5/8 or Eq. 9) and endings."""
        spec = self.spec
        B, N, A = self.num_envs, spec.agents, spec.num_actions
        actions = np.asarray(actions)
        if actions.shape != (B, N):
            raise ValueError(
                f"actions must have shape (num_envs, agents) = {(B, N)}, got {actions.shape}"
            )
        if not np.issubdtype(actions.dtype, np.integer):
            raise ValueError(f"actions must be integers, got {actions.dtype}")
        actions = actions.astype(np.int64, copy=False)
        live = self.active
        out_of_range = (actions < 0) | (actions >= A)
        flat_action = self._agent_offsets + np.clip(actions, 0, A - 1)
        valid = self._mask.reshape(-1)[flat_action]
        bad = live[:, None] & (out_of_range | ~valid)
        if bad.any():
            b, i = np.argwhere(bad)[0]
            raise ValueError(
                f"invalid action {actions[b, i]} for agent {i} in env {b} at cell {self.pos[b, i]} "
                f"(valid: {np.flatnonzero(self._mask[b, i]).tolist()})"
            )

        everyone = live.all()
        rows = self._rows if everyone else np.flatnonzero(live)
        sel = slice(None) if everyone else rows  # a slice indexes faster than arange(B)
        act = actions[sel]
        old = self.pos[sel]
        C = spec.num_cells
        if self._one_table:
            new = self._free_next[old, act]
        else:
            new = self.next_cell.reshape(-1)[(rows[:, None] * C + old) * A + act]
        moved = act != 0
        b = moved.sum(1)
        dist_flat = self.dist.reshape(-1)
        prev_min = dist_flat[rows[:, None] * C + old].min(1)
        new_min = dist_flat[rows[:, None] * C + new].min(1)
        found = new_min == 0

        reward = np.zeros(B, dtype=np.float32)
        if spec.reward == "shaped":  # Eq. 5 / Eq. 8
            reward[sel] = np.where(new_min < prev_min, 1.0, -1.0) - b
        else:  # Eq. 9
            reward[sel] = -b + spec.sparse_bonus * found

        self.pos[sel] = new
        self.cost[sel] += b
        self.t[sel] += 1
        self.idle_streak[sel] = np.where(b == 0, self.idle_streak[sel] + 1, 0)
        self.history[rows, self.t[sel] % HISTORY] = new
        self._take_readings(rows, new)

        terminated = np.zeros(B, dtype=bool)
        truncated = np.zeros(B, dtype=bool)
        terminated[sel] = found
        truncated[sel] = ~found & (self.t[sel] >= spec.max_steps)
        ended = np.flatnonzero(terminated | truncated)
        episode = None
        if len(ended):
            episode = EpisodeStats(
                index=ended,
                found=terminated[ended].copy(),
                length=self.t[ended].copy(),
                cost=self.cost[ended].copy(),
            )
            if self.autoreset:
                self._reset_rows(ended)
            else:
                self.active[ended] = False
        if episode is None:
            going = rows
        else:
            keep = np.ones(B, dtype=bool)
            keep[ended] = False
            going = rows[keep[rows]]
        if len(going):
            self._mask[going] = self._masks(going)
        return StepResult(reward, terminated, truncated, episode)

    @property
    def done(self) -> bool:
        """All episodes over (only with autoreset=False)."""
        return not self.active.any()


def _slab_slant(a_p, a_q, s_p, s_q, length, near, far, size_a, size_s, span) -> np.ndarray:
    """Sum of 1/cos(theta) over the slabs at a = (j + 0.5) * size_a that the segment PQ crosses.

    ``a`` is the coordinate across the slabs, ``s`` the one along them; detectors ``a_p``,
    ``s_p`` are (1, C), sources ``a_q``, ``s_q`` (R, 1); ``near``/``far`` (R, lines) are the run
    lengths from the two sides (0: no wall there). Each env adds its wall lines in increasing
    order, evaluated either for the (env, line) pairs that hold a wall (envs with different
    layouts, as at reset) or line by line over all envs (envs sharing one layout, as the belief
    filter's C hypotheses), whichever touches fewer (env, line) pairs.
    """
    total = np.zeros(length.shape)
    has = (near > 0) | (far > 0)
    rows, lines = np.nonzero(has)  # sorted by env, then line
    if not len(rows):
        return total
    shared = np.flatnonzero(has.any(0))
    if 2 * len(rows) >= len(shared) * len(has):
        for j in shared:
            total += _line_slant(a_p, a_q, s_p, s_q, length, near[:, j : j + 1],
                                 far[:, j : j + 1], j, size_a, size_s, span)
        return total
    add = _line_slant(a_p, a_q[rows], s_p, s_q[rows], length[rows], near[rows, lines][:, None],
                      far[rows, lines][:, None], lines[:, None], size_a, size_s, span)
    rank = np.arange(len(rows)) - np.searchsorted(rows, rows)  # k-th wall line of its env
    for k in range(int(rank.max()) + 1):
        sel = rank == k
        total[rows[sel]] += add[sel]
    return total


def _line_slant(a_p, a_q, s_p, s_q, length, near, far, line, size_a, size_s, span) -> np.ndarray:
    """1/cos(theta) where PQ crosses the wall(s) on slab ``line`` (broadcast), else 0."""
    aw = (line + 0.5) * size_a
    dp, dq = a_p - aw, a_q - aw
    crosses = dp * dq < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        s = s_p + dp / (dp - dq) * (s_q - s_p)
        slant = length / np.abs(a_p - a_q)
    hit = crosses & (((near > 0) & (s <= near * size_s))
                     | ((far > 0) & (s >= (span - far) * size_s)))
    return np.where(hit, slant, 0.0)


def _graph_bfs(target: np.ndarray, next_cell: np.ndarray) -> np.ndarray:
    """(k, C) BFS steps from ``target`` over the moves of ``next_cell`` (k, C, A), one graph
    of k disconnected layouts; invalid moves become self-loops, so every cell has A - 1 edges
    and the sparse layout needs no sorting."""
    k, C, A = next_cell.shape
    moves = next_cell[:, :, 1:]
    base = (np.arange(k) * C)[:, None, None]
    dest = np.where(moves >= 0, moves, np.arange(C)[None, :, None]) + base
    edges = (np.ones(dest.size, dtype=np.float32), dest.reshape(-1),
             np.arange(0, dest.size + 1, A - 1))
    graph = csr_matrix(edges, shape=(k * C, k * C))
    d = dijkstra(graph, indices=np.arange(k) * C + target, unweighted=True)
    d = d.reshape(k, k, C)[np.arange(k), np.arange(k)]
    return np.where(np.isfinite(d), d, UNREACHABLE).astype(np.int32)
