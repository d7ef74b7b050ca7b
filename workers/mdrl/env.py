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

import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import kernels
from .spec import MOVES, EnvSpec

#: BFS distance of cells that cannot reach the target (walls, walled-off pockets).
UNREACHABLE = 1_000_000
#: Positions remembered per env for ``past_pos`` (ODMTL windows need (w - 1) / 2 steps back).
HISTORY = 16
#: Layout draws in a row that may leave a team no room before reset gives up: a valid spec
#: needs a handful at most, one whose walls can enclose no area large enough never succeeds.
MAX_LAYOUT_DRAWS = 100
#: Layouts drawn once per env construction to measure how often the spec's walls leave the
#: team room (a fixed stream of its own: the episodes' layout stream is not touched).
FIT_PROBE_DRAWS = 256
#: Least share of fitting layouts a spec must have: at 20% a reset fails 100 draws in a row
#: with probability 0.8^100 = 2e-10; a spec fitting 3.6% of the time passed one reset and then
#: failed mid-run (2.6% of its resets), its checkpoint unable to get past the failure.
MIN_FIT_RATE = 0.2
#: Above this share of a spec's wall slots (one per non-corner side cell, ``wall_slots``) its
#: most walls take, ``draw_walls`` picks the slots directly (``_draw_walls_direct``) instead of
#: redrawing taken ones (coupon collecting: 25 walls on 10 x 10's 32 slots cost ~1.5 ms a
#: layout). The same layouts in law, not the same stream: below it (every preset) the draws
#: are the ones recorded figures and models were made with, bit for bit.
DENSE_WALLS_SHARE = 0.25
#: Under this share of fitting probe layouts, resets draw the layouts that leave the team no
#: room again in a loop over the short rows (``_fitting_layouts``), several candidates per row
#: at a time, instead of splitting the batch and recursing: the same law, another stream. At or
#: above it (every preset fits 99.6-100%) the recursion and its stream are kept bit for bit.
REDRAW_LOOP_FIT_RATE = 0.9
#: Most candidate layouts x cells drawn in one round of ``_fitting_layouts`` (8 MB of keys).
_REDRAW_CELLS = 1 << 20
_FIT_RATES: dict[EnvSpec, float] = {}
"""Share of fitting probe layouts per spec (evaluation builds an env per batch of episodes)."""


class LayoutError(ValueError):
    """The spec's walls leave no area for the team and the target (too many for the grid)."""


#: Geometries (``geometry``) kept at once, and the most bytes they may hold together (a 64 x 64
#: one is 200 MB): evaluation builds an env per batch of episodes, a trainer one per run.
GEOMETRY_CACHE_ENTRIES = 8
GEOMETRY_CACHE_BYTES = 1 << 30


def _frozen(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


class Geometry:
    """The static tables of one grid geometry, read-only and shared by every env built on it
    (``geometry``): cell rows/columns and centres, the wall-free move table, BFS distances and
    expected-count gains, and (built when first asked for) the wall path factors and the log
    gains of the belief filter. They depend only on ``geometry_key(spec)``."""

    def __init__(self, key: tuple) -> None:
        m, n, moves, (cy, cx), dwell_min, detector_area_cm2 = key
        self.key = key
        cell_row, cell_col = np.repeat(np.arange(m), n), np.tile(np.arange(n), m)
        centre_m = np.stack([(cell_row + 0.5) * cy, (cell_col + 0.5) * cx], axis=1)
        step = MOVES[moves]
        nr = cell_row[:, None] + step[None, :, 0]
        nc = cell_col[:, None] + step[None, :, 1]
        inside = (nr >= 0) & (nr < m) & (nc >= 0) & (nc < n)
        # in place, in int32, one axis at a time: the same values as the int64 / (C, C, 2)
        # temporaries the env built at every construction (~1 GB at 64 x 64), in ~0.3 GB
        r32, c32 = cell_row.astype(np.int32), cell_col.astype(np.int32)
        free_dist = np.abs(np.subtract(r32[:, None], r32[None]))
        along = np.abs(np.subtract(c32[:, None], c32[None]))
        (np.add if moves == 4 else np.maximum)(free_dist, along, out=free_dist)
        del along
        d2_cm2 = np.subtract(centre_m[:, None, 0], centre_m[None, :, 0])
        np.square(d2_cm2, out=d2_cm2)
        dx2 = np.subtract(centre_m[:, None, 1], centre_m[None, :, 1])
        d2_cm2 += np.square(dx2, out=dx2)
        del dx2
        d2_cm2 *= 1e4
        np.maximum(d2_cm2, (min(cy, cx) * 100 / 2) ** 2, out=d2_cm2)
        # Eq. 6 per photon/min: dwell * area / (4 pi d^2), in d2_cm2's buffer
        free_gain = np.divide(dwell_min * detector_area_cm2,
                              np.multiply(4 * np.pi, d2_cm2, out=d2_cm2), out=d2_cm2)
        self.cell_row, self.cell_col, self.centre_m = map(_frozen, (cell_row, cell_col, centre_m))
        self.free_next = _frozen(np.where(inside, nr * n + nc, -1))
        self.free_dist, self.free_gain = _frozen(free_dist), _frozen(free_gain)
        self._slant: tuple[np.ndarray, np.ndarray] | None = None
        self._log_gain: dict[float, np.ndarray] = {}

    def slant(self) -> tuple[np.ndarray, np.ndarray]:
        """(slant_y, slant_x) (C, C): 1 / cos(theta) per (source, detector) and slab axis."""
        with _GEOMETRY_LOCK:
            return self._slant_tables()

    def _slant_tables(self) -> tuple[np.ndarray, np.ndarray]:
        if self._slant is None:
            dy = self.centre_m[None, :, 0] - self.centre_m[:, None, 0]  # detector - source
            dx = self.centre_m[None, :, 1] - self.centre_m[:, None, 1]
            length = np.hypot(dy, dx)
            with np.errstate(divide="ignore", invalid="ignore"):
                self._slant = (_frozen(length / np.abs(dy)), _frozen(length / np.abs(dx)))
        return self._slant

    def log_free_gain(self, floor: float) -> np.ndarray:
        """log max(free_gain, floor) (C, C), for the belief filter (one floor kept)."""
        with _GEOMETRY_LOCK:
            if floor not in self._log_gain:
                self._log_gain.clear()
                self._log_gain[floor] = _frozen(np.log(np.maximum(self.free_gain, floor)))
            return self._log_gain[floor]

    @property
    def nbytes(self) -> int:
        tables = [self.cell_row, self.cell_col, self.centre_m, self.free_next, self.free_dist,
                  self.free_gain, *(self._slant or ()), *self._log_gain.values()]
        return sum(a.nbytes for a in tables)


_GEOMETRY: dict[tuple, Geometry] = {}
"""Cached geometries by ``geometry_key``, least recently used first."""
_GEOMETRY_LOCK = threading.RLock()
"""Guards the cache and the tables built lazily: envs are built from threads too (the
gateway's expert checks run in its thread pool)."""


def geometry_key(spec: EnvSpec) -> tuple:
    """The spec fields the static tables depend on: grid, moves, cell size, detector physics."""
    return (spec.rows, spec.cols, spec.moves, tuple(spec.cell_size_m), spec.dwell_min,
            spec.detector_area_cm2)


def _build_geometry(key: tuple) -> Geometry:
    return Geometry(key)


def geometry(spec: EnvSpec) -> Geometry:
    """The read-only static tables of ``spec``'s geometry, built once and cached (bounded by
    ``GEOMETRY_CACHE_ENTRIES`` and ``GEOMETRY_CACHE_BYTES``; an evicted one lives on in the
    envs that hold it)."""
    key = geometry_key(spec)
    with _GEOMETRY_LOCK:
        geo = _GEOMETRY.pop(key, None)
        if geo is None:
            geo = _build_geometry(key)
        _GEOMETRY[key] = geo  # most recently used last
        while len(_GEOMETRY) > 1 and (
            len(_GEOMETRY) > GEOMETRY_CACHE_ENTRIES
            or sum(g.nbytes for g in _GEOMETRY.values()) > GEOMETRY_CACHE_BYTES
        ):
            del _GEOMETRY[next(iter(_GEOMETRY))]
        return geo


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
        self, spec: EnvSpec, num_envs: int = 1, seed: int | None = None, autoreset: bool = True,
        blocks: Sequence[tuple[int, int]] | None = None,
    ) -> None:
        """``blocks``: ``(seed, size)`` of consecutive runs of envs (sizes adding up to
        ``num_envs``; ``seed`` is then unused), each drawing exactly the layouts and reading
        noise an env of that size built with that seed would: evaluation steps several seeded
        chunks of episodes as one batch (``evaluate``). Only with ``autoreset=False``."""
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.spec = spec
        self.num_envs = num_envs
        self.autoreset = autoreset
        B, N, C, A = num_envs, spec.agents, spec.num_cells, spec.num_actions
        self.moves = MOVES[spec.moves]

        # Static geometry, shared by all episodes and by every env of the same geometry: built
        # once (``geometry``, cached) and read-only (C x C tables: 200 MB at 64 x 64).
        geo = geometry(spec)
        self._geometry = geo
        self.cell_row, self.cell_col, self.centre_m = geo.cell_row, geo.cell_col, geo.centre_m
        # (C, A) move table without walls: a valid move goes where it would go without walls,
        # so steps read this one table (which moves the walls allow: ``action_mask``)
        self._free_next = geo.free_next
        # Wall-free BFS distances have a closed form: Manhattan (4 moves) or Chebyshev (8 moves).
        self._free_dist = geo.free_dist
        # Expected count per photon/min without walls (Eq. 6): dwell * area / (4 pi d^2).
        self._free_gain = geo.free_gain

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
        # The int64 table of every env's moves (66 MB at B = 1024 on 30 x 30) is built only when
        # asked for (``next_cell``): masks are computed at the agents' cells from the walls.
        self._next_cell = np.zeros((B, C, A), dtype=np.int64)
        self._next_stale = np.ones(B, dtype=bool)  # rows of _next_cell not rebuilt since reset
        self.active = np.ones(B, dtype=bool)  # False: episode over and frozen (autoreset=False)
        self.history = np.zeros((B, HISTORY, N), dtype=np.int64)
        self._mask = np.zeros((B, N, A), dtype=bool)
        self._rows = np.arange(B)
        self._agent_offsets = np.arange(B * N).reshape(B, N) * A  # flat (b, i, 0) in (B, N, A)
        if spec.walls[1] and C <= self._GEOMETRY_CELLS:
            # 1 / cos(theta) per (source, detector) and slab axis
            self._slant_y, self._slant_x = geo.slant()
        self._check_fit_rate()
        if blocks is None:
            self.seed(seed)
            self.reset()
        else:
            self._reset_blocks(blocks)

    def _check_fit_rate(self) -> None:
        """Refuse a spec whose walls leave the team no room too often (LayoutError): decided
        once, here, not by a reset that gives up in the middle of a run."""
        self._fit_rate = check_layout_fit(self.spec)

    @staticmethod
    def _probe_fit_rate(spec: EnvSpec) -> float:
        """Share of FIT_PROBE_DRAWS layouts (a fixed stream) whose target's area holds the
        team. Always the rejection sampler: the rate, so which specs are refused, stays what
        it was before dense specs got a direct sampler (once per spec: ~10 ms at worst)."""
        rng = np.random.Generator(np.random.PCG64(FIT_PROBE_DRAWS))
        walls = TargetLocalizationEnv._draw_walls_rejection(spec, rng, FIT_PROBE_DRAWS)
        keys = rng.random((FIT_PROBE_DRAWS, spec.num_cells))
        keys[walls] = 2.0
        target = keys.argmin(axis=1)
        fits = np.ones(FIT_PROBE_DRAWS, dtype=bool)  # no walls: every cell reaches the target
        hard = np.flatnonzero(walls.any(axis=1))
        if len(hard):
            dist = kernels.walls_bfs(
                np.ascontiguousarray(target[hard]), np.ascontiguousarray(walls[hard]),
                spec.rows, spec.cols, MOVES[spec.moves], UNREACHABLE,
            )
            fits[hard] = (dist < UNREACHABLE).sum(1) >= spec.agents + 1
        return float(fits.mean())


    # ------------------------------------------------------------------ seeding and state
    def seed(self, seed: int | None) -> None:
        """Two streams: layouts (so policies see the same episodes) and reading noise."""
        layout, noise = np.random.SeedSequence(seed).spawn(2)
        self.layout_rng = np.random.Generator(np.random.PCG64(layout))
        self.noise_rng = np.random.Generator(np.random.PCG64(noise))
        self._noise_blocks: list[np.random.Generator] | None = None  # one stream for all B

    def _reset_blocks(self, blocks: Sequence[tuple[int, int]]) -> None:
        """Start the episodes of ``blocks`` (see ``__init__``): block k's rows are reset from
        its own layout stream and take readings from its own noise stream, in the order an env
        of its size would (rows ascending), so its episodes are that env's bit for bit."""
        sizes = [int(size) for _, size in blocks]
        if self.autoreset:
            raise ValueError("blocks of seeded envs need autoreset=False")
        if not sizes or min(sizes) < 1 or sum(sizes) != self.num_envs:
            raise ValueError(f"block sizes {sizes} must be >= 1 and add up to {self.num_envs}")
        streams = []
        for block_seed, _ in blocks:
            self.seed(block_seed)
            streams.append((self.layout_rng, self.noise_rng))
        self._block_of = np.repeat(np.arange(len(sizes)), sizes)
        self._noise_blocks = [noise for _, noise in streams]
        start = 0
        for (layout, _), size in zip(streams, sizes, strict=True):
            self.layout_rng = layout
            self._reset_rows(np.arange(start, start + size))
            start += size

    _STATE = (
        "pos target walls dist mean_reading readings reading_sum visits episode_id t idle_streak "
        "intensity cost active history _mask"
    ).split()
    """The arrays of ``state_dict``; ``next_cell`` follows from ``walls`` (a checkpoint that
    still holds it loads: it is ignored)."""

    #: Up to this many cells the (C, C) wall path factors are tables (6.5 MB each at 30 x 30).
    _GEOMETRY_CELLS = 1024

    @property
    def next_cell(self) -> np.ndarray:
        """int (B, C, A): destination of every move; -1 off the grid, into a wall or cutting a
        corner. Built from ``walls`` on demand, only for envs reset since the last call (the
        env itself does not need it); a view, do not modify."""
        stale = np.flatnonzero(self._next_stale)
        if len(stale):
            valid = self._valid_moves(self.walls[stale])
            self._next_cell[stale] = np.where(valid, self._free_next, -1)
            self._next_stale[stale] = False
        return self._next_cell

    def state_dict(self) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """(arrays, JSON-able extras) that restore this env exactly, mid-episode included."""
        if self._noise_blocks is not None:
            raise ValueError("an env of seeded blocks (evaluation) has no single state to save")
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
        self._next_stale[...] = True
        self._noise_blocks = None
        self.layout_rng.bit_generator.state = extras["layout_rng"]
        self.noise_rng.bit_generator.state = extras["noise_rng"]

    # ------------------------------------------------------------------ episodes
    def reset(self, seed: int | None = None) -> None:
        """Start new episodes in all B environments (one stream again after ``blocks``)."""
        if seed is not None:
            self.seed(seed)
        self._noise_blocks = None
        self._reset_rows(self._rows)

    def _reset_rows(self, rows: np.ndarray, draw: int = 1) -> None:
        spec, rng = self.spec, self.layout_rng
        R, C, N = len(rows), spec.num_cells, spec.agents
        if self._fit_rate < REDRAW_LOOP_FIT_RATE:  # misfits common: redraw them in a loop
            walls, target, dist = self._fitting_layouts(R)
            self.walls[rows] = walls
            self._next_stale[rows] = True
            reachable = dist < UNREACHABLE
        else:  # the recursion (and stream) every preset's recorded episodes were drawn with
            walls = self.draw_walls(spec, rng, R)
            self.walls[rows] = walls
            self._next_stale[rows] = True

            # Target among free cells; agents at distinct cells that can reach it.
            keys = rng.random((R, C))
            keys[walls] = 2.0
            target = keys.argmin(axis=1)
            dist = self._bfs(target, walls)
            reachable = dist < UNREACHABLE
            short = reachable.sum(1) < N + 1
            if short.any():  # a pocket too small to hold the team: draw those layouts again
                if draw >= MAX_LAYOUT_DRAWS:
                    raise self._no_room()
                self._reset_rows(rows[~short], draw + 1) if (~short).any() else None
                self._reset_rows(rows[short], draw + 1)
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
        self._update_masks(rows)

    def _no_room(self) -> LayoutError:
        spec = self.spec
        return LayoutError(
            f"{MAX_LAYOUT_DRAWS} wall layouts in a row left no area where {spec.agents} agents "
            f"and a target fit ({spec.rows}x{spec.cols}, walls {spec.walls}, "
            f"wall_length {spec.wall_length}): use fewer or shorter walls or a larger grid"
        )

    def _fitting_layouts(self, R: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(walls (R, C), target (R,), dist (R, C)) for R new episodes, each layout and target
        drawn again until the cells that reach the target hold the team: per row, the first
        fitting draw of an i.i.d. sequence, so the law of the recursion (a layout and target
        conditioned on fitting) without its two calls per batch that misfits. Each round draws
        ~2 / fit-rate candidates per row still short in one batch (one ``draw_walls``, one BFS);
        a row that met ``MAX_LAYOUT_DRAWS`` misfits in a row raises ``LayoutError``."""
        spec, rng = self.spec, self.layout_rng
        C, N = spec.num_cells, spec.agents
        walls = np.zeros((R, C), dtype=bool)
        target = np.zeros(R, dtype=np.int64)
        dist = np.zeros((R, C), dtype=np.int32)
        todo = np.arange(R)
        tried = 0
        per = int(np.ceil(2.0 / max(self._fit_rate, 2.0 / MAX_LAYOUT_DRAWS)))
        while len(todo):
            if tried >= MAX_LAYOUT_DRAWS:
                raise self._no_room()
            k = max(1, min(per, MAX_LAYOUT_DRAWS - tried, _REDRAW_CELLS // (len(todo) * C)))
            w = self.draw_walls(spec, rng, len(todo) * k)  # row todo[i]: candidates i*k..i*k+k-1
            keys = rng.random(w.shape)
            keys[w] = 2.0
            t = keys.argmin(axis=1)
            d = self._bfs(t, w)
            fit = ((d < UNREACHABLE).sum(1) >= N + 1).reshape(len(todo), k)
            ok = fit.any(axis=1)
            pick = np.flatnonzero(ok) * k + fit[ok].argmax(axis=1)  # each row's first fit
            done = todo[ok]
            walls[done], target[done], dist[done] = w[pick], t[pick], d[pick]
            todo = todo[~ok]
            tried += k
        return walls, target, dist

    @staticmethod
    def wall_slots(spec: EnvSpec) -> int:
        """Lines a wall can leave a side on: the non-corner cells of the four sides."""
        return 2 * (spec.rows - 2) + 2 * (spec.cols - 2)

    @staticmethod
    def draw_walls(spec: EnvSpec, rng: np.random.Generator, R: int) -> np.ndarray:
        """(R, C) wall maps: each wall leaves a side at a non-corner cell, perpendicular to it.
        Public (a static method) so the walls CAE (``cae.py``) trains on the env's own layouts.
        Specs whose walls take more than ``DENSE_WALLS_SHARE`` of the slots draw them directly
        (the same law, another stream); the others keep the rejection draws."""
        if spec.walls[1] > DENSE_WALLS_SHARE * TargetLocalizationEnv.wall_slots(spec):
            return TargetLocalizationEnv._draw_walls_direct(spec, rng, R)
        return TargetLocalizationEnv._draw_walls_rejection(spec, rng, R)

    @staticmethod
    def _draw_walls_direct(spec: EnvSpec, rng: np.random.Generator, R: int) -> np.ndarray:
        """``_draw_walls_rejection``'s law without its redraws. There, each wall draws a side
        (1/4 each) and a place on it (1 / (cells along it - 2)) until the slot is free: slot s is
        taken next with probability w_s / (sum of w over the free slots), w_s = 1 / (4 (along_s -
        2)), not uniform on a non-square grid. Exponential clocks with rates w_s ring in that
        order (the first of the free ones is s with that probability, and memorylessness starts
        the race again among the rest): the walls are the slots of the ``count`` smallest keys
        Exp(1) / w_s, in increasing order, each with a length drawn as there."""
        m, n = spec.rows, spec.cols
        lo, hi = spec.walls
        walls = np.zeros((R, m, n), dtype=bool)
        count = rng.integers(lo, hi + 1, size=R)
        slot_side = np.repeat(np.arange(4), [n - 2, n - 2, m - 2, m - 2])
        slot_place = np.concatenate([np.arange(1, n - 1)] * 2 + [np.arange(1, m - 1)] * 2)
        scale = np.where(slot_side < 2, 4.0 * (n - 2), 4.0 * (m - 2))  # 1 / w_s
        keys = rng.standard_exponential((R, len(slot_side))) * scale
        slots = np.argsort(keys, axis=1)[:, :hi]  # (R, hi): the order the walls are drawn in
        side = slot_side[slots]
        (lmin_m, lmax_m), (lmin_n, lmax_n) = spec.wall_length_range(m), spec.wall_length_range(n)
        vertical = side < 2  # from the top or bottom: along a column, at most m - 2 long
        length = rng.integers(np.where(vertical, lmin_m, lmin_n),
                              np.where(vertical, lmax_m, lmax_n) + 1)
        length[np.arange(hi)[None, :] >= count[:, None]] = 0
        kernels.mark_wall_sets(walls, side, slot_place[slots], length)
        return walls.reshape(R, -1)

    @staticmethod
    def _draw_walls_rejection(spec: EnvSpec, rng: np.random.Generator, R: int) -> np.ndarray:
        """The original sampler (every preset's layouts): slots taken are drawn again."""
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
            place = rng.integers(1, along - 1)
            # Two walls on one line of one side would merge: draw again so the count is exact.
            again = taken[np.arange(R), side, place]
            while again.any():
                side[again] = rng.integers(0, 4, size=int(again.sum()))
                vertical, along = side < 2, np.where(side < 2, n, m)
                place[again] = rng.integers(1, along[again] - 1)
                again = taken[np.arange(R), side, place]
            taken[np.arange(R), side, place] = True
            lmin = np.where(vertical, *(spec.wall_length_range(s)[0] for s in (m, n)))
            lmax = np.where(vertical, *(spec.wall_length_range(s)[1] for s in (m, n)))
            length = rng.integers(lmin, lmax + 1)
            kernels.mark_wall_sets(walls, side[:, None], place[:, None],
                                   np.where(k < count, length, 0)[:, None])
        return walls.reshape(R, -1)

    def _valid_moves(self, walls: np.ndarray) -> np.ndarray:
        """bool (R, C, A): the move stays on the grid, its destination is free and (a diagonal)
        it does not cut the corner of a wall cell."""
        if not walls.any():
            return np.broadcast_to(self._free_next >= 0, (len(walls), *self._free_next.shape))
        return kernels.valid_moves(
            np.ascontiguousarray(walls, dtype=bool), self.spec.rows, self.spec.cols, self.moves
        )

    def _bfs(self, target: np.ndarray, walls: np.ndarray) -> np.ndarray:
        """(R, C) BFS steps to the target: the closed form without walls, else a queue search
        per layout (``kernels.walls_bfs``; ~10 us for 30 x 30, where the numpy level-by-level
        search on bit rows cost ~80 us per layout at a step's few resets)."""
        dist = self._free_dist[target].copy()
        hard = np.flatnonzero(walls.any(axis=1))
        if len(hard):
            dist[hard] = kernels.walls_bfs(
                np.ascontiguousarray(target[hard]), np.ascontiguousarray(walls[hard]),
                self.spec.rows, self.spec.cols, self.moves, UNREACHABLE,
            )
        return dist

    def walking_steps(self, cells: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """(B, k, C) int32 BFS steps from each of ``cells`` (B, k) to every cell over env b's
        walls (moves are symmetric: from x to the cell = from the cell to x); ``UNREACHABLE``
        where no path goes. ``rows``: the envs ``cells`` belong to (default all B, in order).
        For observers and searchers: it uses only what the agents know (the walls)."""
        cells = np.ascontiguousarray(cells, dtype=np.int64)
        walls = np.asarray(self.walls, dtype=bool)
        walls = np.ascontiguousarray(walls if rows is None else walls[rows])
        return kernels.walking_steps(cells, walls, self.spec.rows, self.spec.cols, self.moves,
                                     UNREACHABLE)

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

    def unit_counts_at(self, cells: np.ndarray, walls: np.ndarray) -> np.ndarray:
        """(R, C): ``out[r, c]`` is the mean reading at cell ``cells[r]`` per unit intensity with
        the source at c, under layout ``walls[r]`` (R, C): column ``cells[r]`` of the matrix
        whose row c is ``expected_counts([c], ...)``, the same values bit for bit."""
        cells = np.ascontiguousarray(cells, dtype=np.int64)
        gain = self._free_gain[cells]  # (R, C): free_gain[c, x] (the table is symmetric)
        walls = np.ascontiguousarray(walls, dtype=bool)
        if not walls.any():
            return gain
        spec = self.spec
        cy, cx = spec.cell_size_m
        slant = kernels.slant_at(cells, walls, self.centre_m, *self._slant_rows(cells),
                                 spec.rows, spec.cols, cy, cx)
        return gain * np.exp(-spec.wall_mu_per_cm * spec.wall_thickness_cm * slant)

    def add_unit_counts(self, sum_log: np.ndarray, sum_gain: np.ndarray, envs: np.ndarray,
                        cells: np.ndarray, d_reading: np.ndarray, d_visits: np.ndarray,
                        floor: float, walls: np.ndarray | None = None) -> None:
        """For the belief filter (belief.py): for each new reading r, at cell ``cells[r]`` of env
        ``envs[r]``, add ``d_reading[r] * log max(g(c, x), floor)`` to ``sum_log[e]`` and
        ``d_visits[r] *
        g(c, x)`` to ``sum_gain[e]`` for every source c, g the unit counts of
        ``unit_counts_at`` under the env's walls; one compiled pass (``kernels.belief_add``).
        ``walls``: the layouts ``envs`` index, when they are not this env's own B (a view of
        some of its envs, ``experts.EnvRows``)."""
        spec = self.spec
        cy, cx = spec.cell_size_m
        cells = np.ascontiguousarray(cells, dtype=np.int64)
        if getattr(self, "_log_floor", None) != floor:
            self._log_free_gain, self._log_floor = self._geometry.log_free_gain(floor), floor
        kernels.belief_add(
            sum_log, sum_gain, np.ascontiguousarray(envs, dtype=np.int64), cells,
            np.ascontiguousarray(d_reading, dtype=np.float64),
            np.ascontiguousarray(d_visits, dtype=np.float64),
            np.ascontiguousarray(self.walls if walls is None else walls), self._free_gain,
            self._log_free_gain, spec.wall_mu_per_cm * spec.wall_thickness_cm, self.centre_m,
            *self._slant_rows(cells), spec.rows, spec.cols, cy, cx, float(np.log(floor)),
        )

    def _slant_rows(self, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(slant_x, slant_y, row): the length over |dx| and |dy| of the pairs (detector
        ``cells[r]``, every source) in row ``row[r]`` (the env's symmetric tables when it has
        them, else computed here; unused without walls)."""
        if hasattr(self, "_slant_x"):
            return self._slant_x, self._slant_y, cells
        if not self.spec.walls[1]:
            zero = np.zeros((1, self.spec.num_cells))
            return zero, zero, np.zeros(len(cells), dtype=np.int64)
        py, px = self.centre_m[cells, 0][:, None], self.centre_m[cells, 1][:, None]
        qy, qx = self.centre_m[None, :, 0], self.centre_m[None, :, 1]  # sources (1, C)
        length = np.hypot(py - qy, px - qx)
        with np.errstate(divide="ignore", invalid="ignore"):
            return (length / np.abs(px - qx), length / np.abs(py - qy),
                    np.arange(len(cells), dtype=np.int64))

    def _transmission(self, target: np.ndarray, walls: np.ndarray) -> np.ndarray:
        """Beer-Lambert exp(-mu t / cos(theta)) per wall crossed by the detector-source line.

        A wall is the run of wall cells that leaves a side; its slab lies on the centre line of
        those cells, from the side to the far edge of its last cell. 1 / cos(theta) is the same
        for every slab of one orientation, so the path factor is that value added once per
        slab crossed (``kernels.wall_slant``).
        """
        spec = self.spec
        m, n = spec.rows, spec.cols
        cy, cx = spec.cell_size_m
        if hasattr(self, "_slant_x"):  # the tables' rows of the sources
            slant_x, slant_y, row = self._slant_x, self._slant_y, target
        else:
            py, px = self.centre_m[None, :, 0], self.centre_m[None, :, 1]  # detectors (1, C)
            qy, qx = self.centre_m[target, 0][:, None], self.centre_m[target, 1][:, None]
            length = np.hypot(py - qy, px - qx)
            with np.errstate(divide="ignore", invalid="ignore"):
                slant_x, slant_y = length / np.abs(px - qx), length / np.abs(py - qy)
            row = np.arange(len(target))
        slant = kernels.wall_slant(
            np.ascontiguousarray(target), np.ascontiguousarray(walls, dtype=bool), self.centre_m,
            slant_x, slant_y, np.ascontiguousarray(row), m, n, cy, cx,
        )
        return np.exp(-spec.wall_mu_per_cm * spec.wall_thickness_cm * slant)

    # ------------------------------------------------------------------ stepping
    def action_mask(self) -> np.ndarray:
        """bool (B, N, A): valid actions now (a view; do not modify)."""
        return self._mask

    def _update_masks(self, rows: np.ndarray) -> None:
        """Recompute ``action_mask`` for envs ``rows`` at the agents' current cells."""
        kernels.action_masks(
            rows, self.pos, self.walls, self.spec.rows, self.spec.cols, self.moves,
            self.idle_streak, self.spec.idle_limit, self._mask,
        )

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
        lam = self.mean_reading[rows[:, None], cells]
        noisy = self.spec.readings == "poisson"
        if noisy and self._noise_blocks is not None:  # each block's rows from its own stream
            taken = np.empty(lam.shape, dtype=np.float64)
            block = self._block_of[rows]
            cuts = [0, *(np.flatnonzero(block[1:] != block[:-1]) + 1).tolist(), len(rows)]
            for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
                taken[lo:hi] = self._noise_blocks[block[lo]].poisson(lam[lo:hi])
        else:
            taken = self.noise_rng.poisson(lam) if noisy else lam
        kernels.record_readings(
            rows, cells, taken.astype(np.float64, copy=False), self.readings, self.visits,
            self.reading_sum,
        )

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

        rows = self._rows if live.all() else np.flatnonzero(live)
        reward = np.zeros(B, dtype=np.float32)
        found = np.zeros(B, dtype=bool)
        kernels.advance(
            rows, actions, self.pos, self._free_next, self.dist, spec.reward == "shaped",
            float(spec.sparse_bonus), reward, found, self.cost, self.t, self.idle_streak,
            self.history,
        )  # a valid move (checked above) is the wall-free one: _free_next
        self._take_readings(rows, self.pos[rows])

        terminated = found
        truncated = np.zeros(B, dtype=bool)
        truncated[rows] = ~found[rows] & (self.t[rows] >= spec.max_steps)
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
            self._update_masks(going)
        return StepResult(reward, terminated, truncated, episode)

    @property
    def done(self) -> bool:
        """All episodes over (only with autoreset=False)."""
        return not self.active.any()


def layout_fit_rate(spec: EnvSpec) -> float:
    """Share of the wall layouts ``spec`` allows that leave the team and a target an area
    (1.0 without walls): the same for every env of a spec (a fixed stream), so cached."""
    if not spec.walls[1]:
        return 1.0
    rate = _FIT_RATES.get(spec)
    if rate is None:
        rate = TargetLocalizationEnv._probe_fit_rate(spec)
        if len(_FIT_RATES) < 1024:
            _FIT_RATES[spec] = rate
    return rate


def check_layout_fit(spec: EnvSpec) -> float:
    """:func:`layout_fit_rate`, or LayoutError when under MIN_FIT_RATE: what env construction
    and the task-spec parser (so the gateway, before a task is paid for) both refuse."""
    rate = layout_fit_rate(spec)
    if rate < MIN_FIT_RATE:
        raise LayoutError(
            f"only {rate:.0%} of the wall layouts this spec allows leave an area where "
            f"{spec.agents} agents and a target fit ({spec.rows}x{spec.cols}, walls "
            f"{spec.walls}, wall_length {spec.wall_length}; at least {MIN_FIT_RATE:.0%} must): "
            "use fewer or shorter walls or a larger grid"
        )
    return rate
