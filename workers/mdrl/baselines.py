"""Baseline search policies the MDRL agents are benchmarked against (thesis Sec. 3.7.6).

Every policy has the same interface as a trained model: ``reset(env)`` once when the ``B``
episodes of a ``TargetLocalizationEnv`` start together, then ``act(env) -> int64 (B, N)``
each step. Actions are always valid under ``env.action_mask()``. Policies also work under
``autoreset=True``: an environment whose step counter is back at 0 after the policy already
acted in it has started a new episode, and its per-episode state is rebuilt.

- ``random``: uniform over the valid actions.
- ``uniform``: zig-zag (boustrophedon) coverage, one band of the grid per agent ([40]).
- ``bayes``: shared grid posterior of the target cell from every reading taken by the team,
  one-step lookahead on the expected team distance ([11, 15]).
- ``oracle``: knows the target; the closest agent walks a shortest path, the others idle. Its
  time and cost both equal min over agents of the BFS distance at the start: a lower bound no
  search can beat (SPEC section 4).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from scipy.optimize import linear_sum_assignment

from workers.mdrl.belief import BeliefFilter

#: all-pairs distance of cells that cannot reach each other (fits int16, never summed).
FAR = 30000


class Policy(Protocol):
    def reset(self, env) -> None: ...

    def act(self, env) -> np.ndarray: ...


# ---------------------------------------------------------------------------- helpers


def all_pairs_distances(env, envs: np.ndarray | None = None) -> np.ndarray:
    """BFS step counts ``D[k, u, v]`` from cell u to cell v on the grid of env ``envs[k]``
    (default: every env), int16. Computed once per episode.

    The env's own move rule (walls, no corner cutting of diagonals; ``env.walking_steps``, one
    compiled BFS per cell, ~3x faster than a sparse-graph shortest-path call); pairs with no
    path, and every pair that starts or ends in a wall, get ``FAR``.
    """
    b, cells = np.shape(env.walls)
    rows = np.arange(b) if envs is None else np.asarray(envs, dtype=np.int64)
    out = np.empty((len(rows), cells, cells), dtype=np.int16)
    sources = np.arange(cells, dtype=np.int64)[None]
    for k, e in enumerate(rows):  # one env at a time: (C, C) int32 is 3 MB at 30 x 30
        out[k] = np.minimum(env.walking_steps(sources, np.array([e]))[0], FAR)
    return out


def _fallback_valid(mask: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """Replace invalid choices by idle if allowed, else the lowest-index valid action."""
    chosen_ok = np.take_along_axis(mask, actions[..., None], axis=-1)[..., 0]
    first_valid = np.argmax(mask, axis=-1)
    return np.where(chosen_ok, actions, first_valid).astype(np.int64)


def step_toward(env, D: np.ndarray, goal: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """One step of a BFS shortest path from each agent to its goal cell (``-1`` = stay idle).

    Among the valid actions, the one whose next cell is closest to the goal wins; ties go to
    the lowest action index (idle first, so an agent on its goal stays put). If idle is masked
    (``idle_limit``), the best moving action is taken instead.
    """
    B, N = env.pos.shape
    b = np.arange(B)[:, None, None]
    nc = np.asarray(env.next_cell)[b, env.pos[:, :, None], np.arange(mask.shape[-1])]  # (B,N,A)
    valid = mask & (nc >= 0)
    g = np.where(goal < 0, 0, goal)
    dn = D[b, np.where(nc >= 0, nc, 0), g[:, :, None]].astype(np.int32)
    dn[~valid] = np.iinfo(np.int32).max
    act = np.argmin(dn, axis=-1)
    act = np.where(goal < 0, 0, act)
    return _fallback_valid(valid, act)


class _EpisodeTracker:
    """Finds environments that started a new episode since the policy last acted (autoreset)."""

    def __init__(self, num_envs: int) -> None:
        self.acted = np.zeros(num_envs, dtype=bool)

    def fresh(self, env) -> np.ndarray:
        new = self.acted & (np.asarray(env.t) == 0)
        self.acted[:] = True
        return new


# ---------------------------------------------------------------------------- random


class RandomPolicy:
    """Uniform over each agent's valid actions, from its own seeded generator."""

    name = "random"
    #: ``evaluate`` steps its chunks of episodes one at a time: its stream spans the batch.
    rows_independent = False

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)

    def reset(self, env) -> None:
        pass

    def act(self, env) -> np.ndarray:
        mask = env.action_mask()
        score = self.rng.random(mask.shape)
        score[~mask] = -1.0
        return np.argmax(score, axis=-1).astype(np.int64)


# ---------------------------------------------------------------------------- oracle


class OraclePolicy:
    """Knows the target: the agent with the smallest BFS distance walks a shortest path.

    Each step it takes the lowest-index action that decreases ``env.dist`` by one; every other
    agent idles. So time = cost = min_i dist(p_i) at the start, the lower bound of both.
    """

    name = "oracle"

    def reset(self, env) -> None:
        pass

    def act(self, env) -> np.ndarray:
        mask = env.action_mask()
        B, N, A = mask.shape
        b = np.arange(B)
        dist = np.asarray(env.dist).astype(np.int64)
        C = dist.shape[1]
        here = dist[b[:, None], env.pos]  # (B, N)
        walker = np.argmin(here, axis=1)
        cell = env.pos[b, walker]
        nc = np.asarray(env.next_cell)[b, cell]  # (B, A)
        dn = dist[b[:, None], np.where(nc >= 0, nc, 0)]
        ok = mask[b, walker] & (nc >= 0) & (dn == here[b, walker][:, None] - 1)
        ok[:, 0] = False
        move = np.where(ok.any(axis=1), np.argmax(ok, axis=1), 0)
        reachable = here[b, walker] < C
        actions = np.zeros((B, N), dtype=np.int64)
        actions[b, walker] = np.where(reachable, move, 0)
        return _fallback_valid(mask, actions)


# ---------------------------------------------------------------------------- uniform


def snake_order(rows: int, cols: int) -> np.ndarray:
    """Cells in boustrophedon order: row 0 left to right, row 1 right to left, ..."""
    grid = np.arange(rows * cols).reshape(rows, cols)
    grid[1::2] = grid[1::2, ::-1]
    return grid.reshape(-1)


class UniformPolicy:
    """Zig-zag coverage ([40], thesis Sec. 3.7.6 (4)): one band of the grid per agent.

    Bands: the free cells in snake order (``snake_order``) are cut into N contiguous pieces of
    (nearly) equal length: bands of whole rows when they split evenly (2 or 5 agents on an open
    10x10), otherwise a band may start or end mid-row. Agents are matched to bands by a
    minimum-total-distance assignment (BFS distance to the nearer end of the band), and sweep
    their band from that end, row by row.

    Path rule: an agent's next waypoint is the first cell of its band sequence that nobody has
    visited yet and that it can reach; it moves one step along a BFS shortest path to it (so it
    walks around walls), ties between equally short steps broken by the lowest action index.
    Once its band is done it heads for the nearest unvisited reachable cell anywhere, so the
    team keeps covering the area until the target is found.
    """

    name = "uniform"
    #: ``evaluate`` steps its chunks of episodes one at a time: it holds B x C x C distance tables.
    rows_independent = False

    def reset(self, env) -> None:
        self._tracker = _EpisodeTracker(env.pos.shape[0])
        self._init(env, np.arange(env.pos.shape[0]))

    def _init(self, env, envs: np.ndarray) -> None:
        B, N = env.pos.shape
        C = env.walls.shape[1]
        if not hasattr(self, "_wp") or self._wp.shape != (B, N, C):
            self._D = np.zeros((B, C, C), dtype=np.int16)
            self._wp = np.full((B, N, C), -1, dtype=np.int64)
            self._len = np.zeros((B, N), dtype=np.int64)
            self._ptr = np.zeros((B, N), dtype=np.int64)
        rows, cols = env.spec.rows, env.spec.cols
        order = snake_order(rows, cols)
        D = all_pairs_distances(env, envs)
        for k, e in enumerate(envs):
            self._D[e] = D[k]
            free = order[~np.asarray(env.walls[e])[order]]
            bands = np.array_split(free, N)
            pos = env.pos[e]
            cost = np.zeros((N, N))
            flip = np.zeros((N, N), dtype=bool)
            for j, band in enumerate(bands):
                if len(band) == 0:
                    cost[:, j] = 0
                    continue
                d_first = self._D[e, pos, band[0]].astype(np.int64)
                d_last = self._D[e, pos, band[-1]].astype(np.int64)
                cost[:, j] = np.minimum(d_first, d_last)
                flip[:, j] = d_last < d_first
            agents, which = linear_sum_assignment(cost)
            self._wp[e] = -1
            for i, j in zip(agents, which, strict=True):
                band = bands[j][::-1] if flip[i, j] else bands[j]
                self._wp[e, i, : len(band)] = band
                self._len[e, i] = len(band)
            self._ptr[e] = 0

    def act(self, env) -> np.ndarray:
        fresh = np.flatnonzero(self._tracker.fresh(env))
        if len(fresh):
            self._init(env, fresh)
        mask = env.action_mask()
        B, N = env.pos.shape
        visited = np.asarray(env.visits) > 0
        b = np.arange(B)[:, None]
        D = self._D
        while True:
            inside = self._ptr < self._len
            wp = np.where(
                inside,
                np.take_along_axis(
                    self._wp, np.minimum(self._ptr, D.shape[1] - 1)[..., None], axis=2
                )[..., 0],
                0,
            )
            done = visited[b, wp] | (D[b, env.pos, wp] >= FAR)
            skip = inside & done
            if not skip.any():
                break
            self._ptr += skip
        inside = self._ptr < self._len
        goal = np.where(inside, wp, -1)
        if not inside.all():
            # band finished: nearest unvisited reachable cell anywhere
            d = D[b, env.pos].astype(np.int64)  # (B, N, C)
            d[np.broadcast_to((visited | np.asarray(env.walls))[:, None, :], d.shape)] = FAR
            near = np.argmin(d, axis=-1)
            near_ok = np.take_along_axis(d, near[..., None], axis=-1)[..., 0] < FAR
            goal = np.where(inside, goal, np.where(near_ok, near, -1))
        return step_toward(env, D, goal, mask)


# ---------------------------------------------------------------------------- bayes


class BayesPolicy:
    """Cooperative Bayesian search ([11, 15], thesis Sec. 3.7.6 (3)) on a shared grid posterior.

    Posterior: ``belief.BeliefFilter`` (the same filter the belief-map observation shows the
    policy networks): hypotheses (target cell c, intensity I_k), every reading of the team
    folded in with the Poisson likelihood of the env's own expected count, visited cells out.

    Decision rule: one-step lookahead on the posterior expected team distance
    ``J = E_P[min_i D(p_i', c)] + move_cost * #moving agents`` (D: BFS steps). Agents choose
    greedily in index order: agent i picks its valid action minimising J with agents < i at
    their chosen next cells and agents > i where they are (ties -> lowest action index).

    Unsticking: E[distance] is flat or lowest at a "median" of the posterior (between two or
    four equally likely cells, say), where no single step pays and a team that idles only
    re-reads the same cells. So if everyone would idle, the agent nearest (BFS) to the most
    probable cell commits to walking there along a shortest path, and keeps walking until that
    cell has been visited (or lost all probability); the others keep deciding greedily. Each
    commitment ends on a new cell, so the search cannot stall. The env's idle mask is always
    respected (a masked idle has J = inf).
    """

    name = "bayes"
    #: ``evaluate`` steps its chunks of episodes one at a time: it holds B x C x C distance tables.
    rows_independent = False

    def __init__(self, move_cost: float = 0.1, intensity_levels: int = 8) -> None:
        if move_cost < 0:
            raise ValueError(f"move_cost must be >= 0, got {move_cost}")
        self.move_cost = float(move_cost)
        self.intensity_levels = int(intensity_levels)

    def reset(self, env) -> None:
        self._tracker = _EpisodeTracker(env.pos.shape[0])
        self.belief = BeliefFilter(env.spec, self.intensity_levels)
        self._init(env, np.arange(env.pos.shape[0]))

    def _init(self, env, envs: np.ndarray) -> None:
        B, N = env.pos.shape
        C = env.walls.shape[1]
        if not hasattr(self, "_D") or self._D.shape != (B, C, C) or self._goal.shape != (B, N):
            self._D = np.zeros((B, C, C), dtype=np.int16)
            self._goal = np.full((B, N), -1, dtype=np.int64)  # committed walks (see act)
        self._D[envs] = all_pairs_distances(env, envs)
        self._goal[envs] = -1

    def act(self, env) -> np.ndarray:
        fresh = np.flatnonzero(self._tracker.fresh(env))
        if len(fresh):
            self._init(env, fresh)
        P = self.belief.posterior(env)
        mask = env.action_mask()
        B, N, A = mask.shape
        b = np.arange(B)
        D = self._D
        nxt = np.asarray(env.next_cell)
        nc = nxt[b[:, None, None], env.pos[:, :, None], np.arange(A)]  # (B, N, A)
        valid = mask & (nc >= 0)
        nc = np.where(valid, nc, env.pos[:, :, None])
        goal = self._goal
        g = np.maximum(goal, 0)
        visited = np.asarray(env.visits) > 0
        goal[(goal >= 0) & (visited[b[:, None], g] | (P[b[:, None], g] <= 0))] = -1
        committed = goal >= 0
        walk = step_toward(env, D, goal, mask)
        nextpos = env.pos.copy()
        actions = np.zeros((B, N), dtype=np.int64)
        penalty = self.move_cost * (np.arange(A) > 0)
        for i in range(N):
            others = [j for j in range(N) if j != i]
            if others:
                m = D[b[:, None], nextpos[:, others]].min(axis=1).astype(np.float64)  # (B, C)
            else:
                m = np.full((B, D.shape[1]), float(FAR))
            cand = D[b[:, None], nc[:, i]].astype(np.float64)  # (B, A, C)
            team = np.minimum(cand, m[:, None, :])  # (B, A, C) team distance after the move
            J = (P[:, None, :] * team).sum(axis=-1) + penalty
            J[~valid[:, i]] = np.inf
            a = np.where(committed[:, i], walk[:, i], np.argmin(J, axis=1))
            actions[:, i] = a
            nextpos[:, i] = nc[b, i, a]
        # Nobody wants to move: the team sits at a "median" of the posterior. The agent nearest
        # to the most probable cell commits to walking there until that cell has been visited.
        stuck = (actions == 0).all(axis=1) & (P.max(axis=1) > 0)
        if stuck.any():
            best = np.argmax(P, axis=1)
            d = D[b[:, None], env.pos, best[:, None]]  # (B, N)
            mover = np.argmin(d, axis=1)
            stuck &= d[b, mover] < FAR
            goal[b[stuck], mover[stuck]] = best[stuck]
            walk = step_toward(env, D, goal, mask)
            actions[b[stuck], mover[stuck]] = walk[b[stuck], mover[stuck]]
        return _fallback_valid(valid, actions)


# ---------------------------------------------------------------------------- registry

BASELINES = ("random", "uniform", "bayes", "oracle")


def make_baseline(name: str, seed: int = 0) -> Policy:
    """A baseline policy by name (``BASELINES``); ``seed`` feeds the random policy."""
    if name == "random":
        return RandomPolicy(seed)
    if name == "uniform":
        return UniformPolicy()
    if name == "bayes":
        return BayesPolicy()
    if name == "oracle":
        return OraclePolicy()
    raise ValueError(f"unknown baseline {name!r}; expected one of {', '.join(BASELINES)}")
