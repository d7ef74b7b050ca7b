"""The team's posterior over the target cell from every reading taken so far (Bayes' rule).

One filter, two users: the Bayesian searcher (``baselines.BayesPolicy``) decides on it, and
the belief-map observation (``ObservationSpec(belief=True)``) shows it to the policy network.

Model (the environment's own, thesis Eq. 6): if the target is at cell c with intensity I, a
reading at cell x is Poisson with mean ``I * g(c, x)``, where ``g`` is the env's expected count
per unit intensity (``env.expected_counts``: inverse square law times wall transmission).
Readings are independent, so the log-likelihood of hypothesis (c, I) given all readings is

    sum_x S_x log(I g(c, x)) - n_x I g(c, x)        (constants dropped)

with ``S_x`` the sum of the readings taken at x (``env.reading_sum``) and ``n_x`` how many were
taken there (``env.visits``): two matrix products per step, whatever the episode length.
Prior: uniform over free cells connected to the agents, times ``intensity_hypotheses`` (the
intensity is marginalised out). Cells visited without finding the target get probability 0.
Under ``readings="expected"`` the same likelihood peaks at the true hypothesis (it is the
Poisson likelihood of the noise-free counts), so one filter serves both reading models.

Nothing here looks at the target: only walls, positions, readings and visits, which the
agents observe.
"""

from __future__ import annotations

import weakref
from typing import Any

import numpy as np
from scipy import ndimage

#: floor of the unit count before taking logs (a wall can attenuate a count to ~0).
_TINY = 1e-30


def intensity_hypotheses(spec: Any, levels: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Intensities the filter considers and their prior weights.

    fixed: the value; choice: each value, equal odds; uniform(lo, hi): the mid-points of
    ``levels`` equal-width bins, equal odds (a discretised uniform prior).
    """
    it = spec.intensity
    if it.kind == "uniform":
        lo, hi = it.values
        edges = np.linspace(lo, hi, levels + 1)
        vals = (edges[:-1] + edges[1:]) / 2 if hi > lo else np.array([lo])
    else:
        vals = np.unique(np.asarray(it.values, dtype=np.float64))
    return vals, np.full(len(vals), 1.0 / len(vals))


def unit_counts(env: Any, walls: np.ndarray) -> np.ndarray:
    """``G[c, x]`` (C, C) float64: expected count at x per unit intensity, target at c, for
    one wall map (C,). Uses ``env.expected_counts``: exactly the model that makes readings."""
    c = walls.shape[0]
    return env.expected_counts(np.arange(c), np.broadcast_to(walls, (c, c)), np.ones(c))


class BeliefFilter:
    """P(target = c | readings) for the B envs of a ``TargetLocalizationEnv``.

    ``posterior(env) -> (B, C)``; stateless in the readings (it recomputes from the env's
    sufficient statistics), cached in the geometry: the unit-count matrices are computed once
    per wall layout (shared by all envs when the spec has no walls).
    """

    def __init__(self, spec: Any, intensity_levels: int = 8) -> None:
        values, prior = intensity_hypotheses(spec, intensity_levels)
        self.intensities = values
        self._log_i = np.log(values)
        self._log_prior = np.log(prior)
        self._shared = spec.walls[1] == 0  # no walls: one geometry for every env
        self._env: weakref.ref | None = None
        self._walls: np.ndarray | None = None

    # ------------------------------------------------------------------ geometry cache
    def _prepare(self, env: Any) -> None:
        walls = np.asarray(env.walls, dtype=bool)
        b, c = walls.shape
        if self._env is None or self._env() is not env or self._walls is None \
                or self._walls.shape != walls.shape:
            self._env = weakref.ref(env)
            self._walls = np.zeros_like(walls)
            if self._shared:
                g = unit_counts(env, np.zeros(c, dtype=bool))
                self._gt = np.ascontiguousarray(g.T)  # (x, c)
                self._log_gt = np.log(np.maximum(self._gt, _TINY))
                self._labels = None
                return
            self._gt = np.empty((b, c, c), dtype=np.float32)
            self._log_gt = np.empty((b, c, c), dtype=np.float32)
            self._labels = np.zeros((b, c), dtype=np.int32)
            stale = np.arange(b)
        elif self._shared:
            return
        else:
            stale = np.flatnonzero((self._walls != walls).any(axis=1))
        rows, cols = env.spec.rows, env.spec.cols
        for e in stale:
            g = unit_counts(env, walls[e])
            self._gt[e] = g.T
            self._log_gt[e] = np.log(np.maximum(g.T, _TINY))
            # moves never cut corners, so diagonal reachability is 4-connected reachability
            self._labels[e] = ndimage.label(~walls[e].reshape(rows, cols))[0].reshape(-1)
            self._walls[e] = walls[e]

    # ------------------------------------------------------------------ posterior
    def log_likelihood(self, env: Any) -> np.ndarray:
        """(B, K, C) log P(readings | target c, intensity I_k) + log prior(I_k), up to a
        constant per env; -inf where the target cannot be (walls, other pockets, visited)."""
        self._prepare(env)
        s = np.asarray(env.reading_sum, dtype=np.float64)
        n = np.asarray(env.visits, dtype=np.float64)
        if self._shared:
            a = s @ self._log_gt  # (B, C): sum_x S_x log g(c, x)
            m = n @ self._gt  # (B, C): sum_x n_x g(c, x)
        else:
            a = np.matmul(s[:, None, :].astype(np.float32), self._log_gt)[:, 0].astype(np.float64)
            m = np.matmul(n[:, None, :].astype(np.float32), self._gt)[:, 0].astype(np.float64)
        total = s.sum(axis=1)
        ll = (a[:, None, :] + (total[:, None] * self._log_i)[:, :, None]
              - self.intensities[None, :, None] * m[:, None, :]
              + self._log_prior[None, :, None])
        ll[np.broadcast_to(~self.allowed(env)[:, None, :], ll.shape)] = -np.inf
        return ll

    def allowed(self, env: Any) -> np.ndarray:
        """(B, C) bool: cells the target may still occupy (free, connected to the team,
        not visited)."""
        self._prepare(env)
        ok = ~np.asarray(env.walls, dtype=bool) & ~(np.asarray(env.visits) > 0)
        if self._labels is not None:
            lead = np.asarray(env.pos)[:, 0]
            b = np.arange(len(lead))
            ok &= self._labels == self._labels[b, lead][:, None]
        return ok

    def posterior(self, env: Any) -> np.ndarray:
        """(B, C) float64: P(target = c | every reading of the team), intensity marginalised."""
        ll = self.log_likelihood(env)
        top = ll.max(axis=(1, 2), keepdims=True)
        top = np.where(np.isfinite(top), top, 0.0)
        p = np.exp(ll - top).sum(axis=1)
        total = p.sum(axis=1, keepdims=True)
        return np.divide(p, total, out=np.zeros_like(p), where=total > 0)
