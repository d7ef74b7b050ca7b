"""Batched multi-agent target localization: one object steps B environments as arrays.

Thesis Ch. 3.2/3.7.1 (Poisson readings, Eq. 6; team rewards Eq. 5/8 and Eq. 9) and Ch. 4.3-4.4
(walls from the sides, 8 directions + idle, invalid-move masks, the all-idle rule). What is fixed
within an episode (BFS distance map, expected-reading map, which moves the walls allow) is
computed once at reset, so a step is a handful of gathers over (B, N) arrays.

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
        # A spec without walls gives every env this table: masks read the small shared table
        # instead of gathering from _valid (B * C * A entries, far beyond the caches). Steps
        # always read it: a valid move goes where it would go without walls.
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
        # Which moves the walls allow, per env and cell: the move itself is always the wall-free
        # one (``_free_next``), so bools are all a step needs (the int64 table ``next_cell`` is
        # 8x larger, 66 MB at B = 1024 on 30 x 30, and is built only when asked for).
        self._valid = np.zeros((B, C, A), dtype=bool)
        self._next_cell = np.zeros((B, C, A), dtype=np.int64)
        self._next_stale = np.ones(B, dtype=bool)  # rows of _next_cell not rebuilt since reset
        self.active = np.ones(B, dtype=bool)  # False: episode over and frozen (autoreset=False)
        self.history = np.zeros((B, HISTORY, N), dtype=np.int64)
        self._mask = np.zeros((B, N, A), dtype=bool)
        self._rows = np.arange(B)
        self._agent_offsets = np.arange(B * N).reshape(B, N) * A  # flat (b, i, 0) in (B, N, A)
        if spec.walls[1] == 0:
            self._valid[...] = self._free_next >= 0
        elif C <= self._GEOMETRY_CELLS:  # 1 / cos(theta) per (source, detector) and slab axis
            dy = self.centre_m[None, :, 0] - self.centre_m[:, None, 0]  # detector - source
            dx = self.centre_m[None, :, 1] - self.centre_m[:, None, 1]
            length = np.hypot(dy, dx)
            with np.errstate(divide="ignore", invalid="ignore"):
                self._slant_y, self._slant_x = length / np.abs(dy), length / np.abs(dx)
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
        "intensity cost active history _mask"
    ).split()
    """The arrays of ``state_dict``; ``next_cell`` and ``_valid`` follow from ``walls`` (a
    checkpoint that still holds ``next_cell`` loads: it is ignored)."""

    #: Up to this many cells the (C, C) wall path factors are tables (6.5 MB each at 30 x 30).
    _GEOMETRY_CELLS = 1024

    @property
    def next_cell(self) -> np.ndarray:
        """int (B, C, A): destination of every move; -1 off the grid, into a wall or cutting a
        corner. Built from ``walls`` on demand, only for envs reset since the last call (the
        env itself only needs ``_valid``); a view, do not modify."""
        stale = np.flatnonzero(self._next_stale)
        if len(stale):
            self._next_cell[stale] = np.where(self._valid[stale], self._free_next, -1)
            self._next_stale[stale] = False
        return self._next_cell

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
        self._valid[...] = self._valid_moves(self.walls)
        self._next_stale[...] = True
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
        if spec.walls[1]:  # without walls every env keeps the table set in __init__
            self._valid[rows] = self._valid_moves(walls)
            self._next_stale[rows] = True

        # Target among free cells; agents at distinct cells that can reach it.
        keys = rng.random((R, C))
        keys[walls] = 2.0
        target = keys.argmin(axis=1)
        dist = self._bfs(target, walls)
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
            lmin = np.where(vertical, *(spec.wall_length_range(s)[0] for s in (m, n)))
            lmax = np.where(vertical, *(spec.wall_length_range(s)[1] for s in (m, n)))
            length = rng.integers(lmin, lmax + 1)
            # the wall's cells, counted from its side: step j of the wall is at depth j
            depth = np.arange(max(m, n))[None, :]
            deep = np.where(side[:, None] % 2 == 0, depth, span[:, None] - 1 - depth)
            r = np.where(vertical[:, None], deep, place[:, None])
            c = np.where(vertical[:, None], place[:, None], deep)
            on = (depth < length[:, None]) & (k < count)[:, None]
            b = np.broadcast_to(np.arange(R)[:, None], on.shape)
            walls[b[on], r[on], c[on]] = True
        return walls.reshape(R, -1)

    def _valid_moves(self, walls: np.ndarray) -> np.ndarray:
        """bool (R, C, A): the move stays on the grid, its destination is free and (a diagonal)
        it does not cut the corner of a wall cell."""
        R = len(walls)
        if not walls.any():
            return np.broadcast_to(self._free_next >= 0, (R, *self._free_next.shape))
        m, n, A = self.spec.rows, self.spec.cols, self.spec.num_actions
        free = np.zeros((R, m + 2, n + 2), dtype=bool)  # a border of walls around the grid
        free[:, 1:-1, 1:-1] = ~walls.reshape(R, m, n)
        valid = np.empty((R, m, n, A), dtype=bool)
        for a, (dr, dc) in enumerate(self.moves):
            ok = valid[..., a]
            np.copyto(ok, free[:, 1 + dr : m + 1 + dr, 1 + dc : n + 1 + dc])  # destination free
            if dr and dc:  # a diagonal needs both orthogonal neighbours free (no corner cutting)
                ok &= free[:, 1 + dr : m + 1 + dr, 1 : n + 1]
                ok &= free[:, 1 : m + 1, 1 + dc : n + 1 + dc]
        return valid.reshape(R, m * n, A)

    def _bfs(self, target: np.ndarray, walls: np.ndarray) -> np.ndarray:
        """(R, C) BFS steps to the target (moves are symmetric, so search from the target).

        Without walls: the closed form. With walls: level by level, on bit rows (one uint64 per
        grid row, bit c = column c) when the grid has at most 64 columns, else on bool grids.
        A level of the bit search is ~10 array operations on (3, R, rows) words, so a reset's
        few layouts cost ~0.8 ms (a scipy graph search per layout cost ~1.5 ms for ten) and
        all 1024 at once ~40 ms (the bool grids: ~700 ms).
        """
        dist = self._free_dist[target].copy()
        hard = np.flatnonzero(walls.any(axis=1))
        if len(hard):
            search = self._bit_bfs if self.spec.cols <= 64 else self._grid_bfs
            dist[hard] = search(target[hard], walls[hard])
        return dist

    def _bit_bfs(self, target: np.ndarray, walls: np.ndarray) -> np.ndarray:
        """``_bfs`` for layouts with walls, rows as bit masks. A cell y joins the next level if
        it is free and unseen and a move from a frontier cell x reaches it: a straight one, or
        a diagonal (dr, dc) whose orthogonal cells x + (0, dc) and x + (dr, 0) = y - (0, dc)
        are free (as in ``_valid_moves``). Levels are recorded as binary digits (bit planes)."""
        k, m, n = len(target), self.spec.rows, self.spec.cols
        grid = np.zeros((k, m, 64), dtype=bool)
        grid[:, :, :n] = ~walls.reshape(k, m, n)
        free = np.zeros((k, m + 2), dtype=np.uint64)  # rows 0 and m + 1: off the grid
        free[:, 1:-1] = np.packbits(grid, axis=-1, bitorder="little").view("<u8")[..., 0]
        inner = free[:, 1:-1]
        one = np.uint64(1)
        # a diagonal into y with column step dc needs y and y - (0, dc) free
        corner = np.stack([inner & (inner << one), inner & (inner >> one)])
        tr, tc = np.divmod(target, n)
        # moves[0]: the frontier, moves[1], moves[2]: its free cells one column right, left
        moves = np.zeros((3, k, m + 2), dtype=np.uint64)
        front = moves[0]
        front[np.arange(k), tr + 1] = one << tc.astype(np.uint64)
        unseen = inner & ~front[:, 1:-1]
        rows_on = np.empty((3, k, m), dtype=np.uint64)
        levels = np.zeros((64, k, m), dtype=np.uint64)  # levels[d]: cells at distance d
        d = 0
        while True:
            d += 1
            if d == len(levels):
                levels = np.concatenate([levels, np.zeros_like(levels)])
            reached = levels[d]
            np.left_shift(front, one, out=moves[1])
            np.right_shift(front, one, out=moves[2])
            moves[1:] &= free
            np.bitwise_or(moves[:, :, :-2], moves[:, :, 2:], out=rows_on)  # one row up or down
            if self.spec.moves == 8:
                rows_on[1:] &= corner  # diagonals
            else:
                rows_on[1:] = 0
            rows_on[1:] |= moves[1:, :, 1:-1]  # left and right
            np.bitwise_or.reduce(rows_on, axis=0, out=reached)
            reached &= unseen
            unseen ^= reached
            front[:, 1:-1] = reached
            if d % 4 == 0 and not reached.any():  # an empty level: all later ones are too
                break
        digits = np.arange(d + 1)[:, None] >> np.arange(max(d.bit_length(), 1))[None, :] & 1
        planes = [
            np.bitwise_or.reduce(levels[: d + 1][digits[:, j] == 1], axis=0)
            for j in range(digits.shape[1])
        ]  # planes[j]: distance has binary digit j
        dist = np.zeros((k, m, n), dtype=np.int32)
        for j, plane in enumerate(planes):
            bits = np.unpackbits(
                plane.astype("<u8").view(np.uint8).reshape(k, m, 8), axis=-1, bitorder="little"
            )[..., :n]
            dist += bits.astype(np.int32) << j
        lost = np.unpackbits(
            (unseen | ~inner).astype("<u8").view(np.uint8).reshape(k, m, 8),
            axis=-1,
            bitorder="little",
        )[..., :n].astype(bool)
        dist[lost] = UNREACHABLE  # walls and free cells the search never reached
        return dist.reshape(k, m * n)

    def _grid_bfs(self, target: np.ndarray, walls: np.ndarray) -> np.ndarray:
        """``_bfs`` for layouts with walls on bool grids (any width): a cell joins the next level
        if a move from the current level reaches it, i.e. it is free and (for a diagonal) both
        orthogonal cells beside the move are free, as in ``_valid_moves``."""
        m, n, k = self.spec.rows, self.spec.cols, len(target)
        free = np.zeros((k, m + 2, n + 2), dtype=bool)  # a border of walls around the grid
        inner = free[:, 1:-1, 1:-1]
        inner[...] = ~walls.reshape(k, m, n)
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
        tr, tc = np.divmod(target, n)
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
        return sub.reshape(k, m * n)

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
        those cells, from the side to the far edge of its last cell. 1 / cos(theta) is the same
        for every slab of one orientation, so the path factor is that value times the number
        of such slabs crossed (added up one slab at a time, as float sums go: ``_times``).
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
        if hasattr(self, "_slant_x"):
            slant_x, slant_y = self._slant_x[target], self._slant_y[target]
        else:
            length = np.hypot(py - qy, px - qx)
            with np.errstate(divide="ignore", invalid="ignore"):
                slant_x, slant_y = length / np.abs(px - qx), length / np.abs(py - qy)
        top = np.cumprod(grid, axis=1).sum(1)  # (R, n) run down from the top of each column
        bottom = np.cumprod(grid[:, ::-1], axis=1).sum(1)
        left = np.cumprod(grid, axis=2).sum(2)  # (R, m) run in from the left of each row
        right = np.cumprod(grid[:, :, ::-1], axis=2).sum(2)
        slant = _times(slant_x, _slabs_hit(px, qx, py, qy, top, bottom, cx, cy, m))
        slant += _times(slant_y, _slabs_hit(py, qy, px, qx, left, right, cy, cx, n))
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
            flat = self._valid.reshape(-1, self.spec.num_actions)
            mask = np.take(flat, rows[:, None] * C + self.pos[rows], axis=0)
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
        new = self._free_next[old, act]  # a valid move (checked above) is the wall-free one
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


def _slabs_hit(a_p, a_q, s_p, s_q, near, far, size_a, size_s, span) -> np.ndarray:
    """(R, C) number of wall slabs at a = (j + 0.5) * size_a that the segment PQ crosses.

    ``a`` is the coordinate across the slabs, ``s`` the one along them; detectors ``a_p``,
    ``s_p`` are (1, C), sources ``a_q``, ``s_q`` (R, 1); ``near``/``far`` (R, lines) are the run
    lengths from the two sides (0: no wall there). Evaluated either for the (env, line) pairs
    that hold a wall (envs with different layouts, as at reset) or line by line over all envs
    (envs sharing one layout, as the belief filter's C hypotheses), whichever touches fewer
    (env, line) pairs.
    """
    count = np.zeros((len(a_q), a_p.shape[1]), dtype=np.uint8)
    has = (near > 0) | (far > 0)
    rows, lines = np.nonzero(has)  # sorted by env, then line
    if not len(rows):
        return count
    shared = np.flatnonzero(has.any(0))
    if 2 * len(rows) >= len(shared) * len(has):
        for j in shared:
            count += _line_hits(
                a_p, a_q, s_p, s_q, near[:, j : j + 1], far[:, j : j + 1], j, size_a, size_s, span
            )
        return count
    hit = _line_hits(
        a_p,
        a_q[rows],
        s_p,
        s_q[rows],
        near[rows, lines][:, None],
        far[rows, lines][:, None],
        lines[:, None],
        size_a,
        size_s,
        span,
    )
    if len(a_q) * len(rows) <= 4096:  # a few envs (a step's resets): one small product
        pick = np.zeros((len(a_q), len(rows)), dtype=np.float32)  # env <- its pairs
        pick[rows, np.arange(len(rows))] = 1.0
        return (pick @ hit.astype(np.float32)).astype(np.uint8)  # small counts: exact
    first = np.flatnonzero(np.r_[True, rows[1:] != rows[:-1]])  # each env's first pair
    count[rows[first]] = np.add.reduceat(hit, first, axis=0)
    return count


def _line_hits(a_p, a_q, s_p, s_q, near, far, line, size_a, size_s, span) -> np.ndarray:
    """uint8 1 where PQ crosses the wall(s) on slab ``line`` (broadcast), else 0."""
    aw = (line + 0.5) * size_a
    dp, dq = a_p - aw, a_q - aw
    with np.errstate(divide="ignore", invalid="ignore"):
        s = s_p + dp / (dp - dq) * (s_q - s_p)
    hit = ((near > 0) & (s <= near * size_s)) | ((far > 0) & (s >= (span - far) * size_s))
    hit &= dp * dq < 0
    return hit.view(np.uint8)


def _times(value: np.ndarray, count: np.ndarray) -> np.ndarray:
    """``value`` added up ``count`` times from 0.0 (0 where ``count`` is 0, whatever ``value``).

    Sums of 1, 2 or 3 equal terms are their products (x + x = 2x exactly, 2x + x = 3x rounded
    once); from 4 terms on the sums go one term at a time, as a float sum does.
    """
    top = int(count.max()) if count.size else 0
    if top <= 3:
        with np.errstate(invalid="ignore"):
            return np.where(count > 0, value * count, 0.0)
    total = np.zeros(count.shape)
    for k in range(top):
        total += np.where(count > k, value, 0.0)
    return total
