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

    ``posterior(env) -> (B, C)``. It keeps, per env, the two sums of the log-likelihood
    (module doc), ``a[c] = sum_x S_x log g(c, x)`` and ``m[c] = sum_x n_x g(c, x)``, and adds
    to them only what changed since the last call: one column ``g(., x)`` of the unit counts
    (``env.add_unit_counts``, compiled) per newly visited cell x. A step thus costs O(N C) per env,
    whatever the grid or the walls, where the whole C x C matrix per layout (6.5 MB and ~60 ms
    per reset at 30 x 30) made the filter too costly beyond the 10 x 10 scale-down. A new
    episode (``env.episode_id``), another env object, or statistics that went back (a restored
    state) start an env's sums over from its readings, so the result depends only on the env's
    state, as a filter recomputed from scratch would.
    """

    def __init__(self, spec: Any, intensity_levels: int = 8) -> None:
        values, prior = intensity_hypotheses(spec, intensity_levels)
        self.intensities = values
        self._log_i = np.log(values)
        self._log_prior = np.log(prior)
        self._walls_possible = spec.walls[1] > 0
        self._env: weakref.ref | None = None

    # ------------------------------------------------------------------ running sums
    def _sync(self, env: Any) -> None:
        """Bring every env's sums (and its pocket labels) up to the env's readings."""
        s = np.asarray(env.reading_sum, dtype=np.float64)
        n = np.asarray(env.visits, dtype=np.float64)
        walls = np.asarray(env.walls, dtype=bool)
        episode = np.asarray(env.episode_id)
        b, c = s.shape
        if self._env is None or self._env() is not env or self._a.shape != (b, c):
            self._env = weakref.ref(env)
            self._a, self._m = np.zeros((b, c)), np.zeros((b, c))
            self._s, self._n = np.zeros((b, c)), np.zeros((b, c))
            self._episode = np.full(b, -1, dtype=np.int64)
            self._walls = np.zeros((b, c), dtype=bool)
            self._labels = np.zeros((b, c), dtype=np.int32) if self._walls_possible else None
        ds, dn = s - self._s, n - self._n
        restart = ((self._episode != episode) | (dn < 0).any(axis=1)
                   | (self._walls != walls).any(axis=1))
        if restart.any():
            e = np.flatnonzero(restart)
            self._a[e], self._m[e] = 0.0, 0.0
            ds[e], dn[e] = s[e], n[e]
            self._episode[e], self._walls[e] = episode[e], walls[e]
            if self._labels is not None:
                rows, cols = env.spec.rows, env.spec.cols
                for i in e:
                    # moves never cut corners: diagonal reachability is 4-connected reachability
                    self._labels[i] = ndimage.label(~walls[i].reshape(rows, cols))[0].reshape(-1)
        envs, cells = np.nonzero((dn != 0) | (ds != 0))
        if len(cells):
            env.add_unit_counts(self._a, self._m, envs, cells, ds[envs, cells], dn[envs, cells],
                                _TINY)
        self._s[:], self._n[:] = s, n

    # ------------------------------------------------------------------ posterior
    def log_likelihood(self, env: Any) -> np.ndarray:
        """(B, K, C) log P(readings | target c, intensity I_k) + log prior(I_k), up to a
        constant per env; -inf where the target cannot be (walls, other pockets, visited)."""
        self._sync(env)
        a, m = self._a, self._m  # (B, C): sum_x S_x log g(c, x), sum_x n_x g(c, x)
        total = self._s.sum(axis=1)
        ll = (a[:, None, :] + (total[:, None] * self._log_i)[:, :, None]
              - self.intensities[None, :, None] * m[:, None, :]
              + self._log_prior[None, :, None])
        ll[np.broadcast_to(~self.allowed(env)[:, None, :], ll.shape)] = -np.inf
        return ll

    def allowed(self, env: Any) -> np.ndarray:
        """(B, C) bool: cells the target may still occupy (free, connected to the team,
        not visited)."""
        self._sync(env)
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
