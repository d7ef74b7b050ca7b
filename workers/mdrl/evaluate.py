"""Evaluate a policy on a fixed, seeded set of episodes (thesis Sec. 3.7.3, 3.7.6).

Localization time = episode length in steps (``max_steps`` when the target is not found);
cost = moving actions of the whole team in the episode (line 577). Episodes are drawn by
``TargetLocalizationEnv`` with ``autoreset=False`` in chunks of ``batch`` environments; chunk
j is seeded from ``(seed, j)``, so the same ``(spec, episodes, seed, batch)`` gives the very
same layouts (targets, starts, walls, intensities) to every policy, and the same reading
noise too as long as the policies' choices agree.

Chunks are what the episodes are; how many are stepped at once is not: a policy whose choice
in one env does not depend on the others in the batch (a trained model; not ``random``, whose
stream is drawn over the batch, nor the baselines holding B x C x C tables) steps up to
``STEP_ENVS`` envs of consecutive chunks as one env (``TargetLocalizationEnv(blocks=...)``,
each chunk with its own streams), so a large grid, whose chunks hold one or a few episodes,
is not stepped one episode at a time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from .env import TargetLocalizationEnv
from .spec import EnvSpec

Z95 = 1.959963984540054
#: Most envs stepped together by ``evaluate`` when it groups chunks (~1 MB each at 64 x 64,
#: env and observer).
STEP_ENVS = 100
MAX_EPISODES = 1_000_000
"""Most episodes one ``evaluate`` runs: the chunk list and the per-episode arrays are built
up front, so 10^11 episodes took the machine's memory (the OOM killer) before the first step."""


def default_batch(spec: EnvSpec, episodes: int) -> int:
    """Episodes per seeded chunk; depends on the spec only, never on the policy (so every
    policy gets the same episodes).

    Bounded so the per-episode all-pairs tables of the baselines (B x C x C) stay small; other
    policies step several chunks together (``evaluate``), so the bound does not slow them.
    """
    C = spec.num_cells
    return int(max(1, min(episodes, 100, 20_000_000 // (C * C))))


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial rate (good near 0 and 1, unlike the normal one)."""
    if n == 0:
        return (math.nan, math.nan)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    lo = 0.0 if successes == 0 else max(0.0, centre - half)  # exact bounds at 0 and n
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return (lo, hi)


def t_interval(values: np.ndarray) -> tuple[float, float]:
    """Student-t 95% interval of a mean: mean +- t_{0.975, n-1} s / sqrt(n)."""
    values = np.asarray(values, dtype=np.float64)
    n = len(values)
    if n == 0:
        return (math.nan, math.nan)
    mean = float(values.mean())
    if n == 1:
        return (math.nan, math.nan)
    half = float(stats.t.ppf(0.975, n - 1) * values.std(ddof=1) / math.sqrt(n))
    return (mean - half, mean + half)


def _clipped(interval: tuple[float, float], low: float) -> list[float]:
    """``interval`` cut to the support ``[low, inf)`` (a t interval on few skewed values can
    reach below the least possible value: an episode lasts >= 1 step and costs >= 0)."""
    return [x if math.isnan(x) else max(x, low) for x in interval]


def _mean(values: np.ndarray) -> float:
    return float(np.mean(values)) if len(values) else math.nan


@dataclass
class EvalReport:
    """Outcome of ``evaluate``: per-episode arrays and summary figures with 95% intervals.

    ``time_mean`` / ``cost_mean`` average over ALL episodes (a failed episode counts
    ``max_steps`` steps and the moves it made); ``*_success`` average over the successful
    episodes only (NaN if none). Rates use the Wilson interval, means the Student-t interval
    cut to the support (time >= 1 step, cost >= 0 moves).
    """

    policy: str
    spec: EnvSpec
    seed: int
    batch: int
    found: np.ndarray  # bool (E,)
    time: np.ndarray  # int64 (E,) episode length
    cost: np.ndarray  # int64 (E,) moving actions of the team
    target: np.ndarray  # int64 (E,) target cell (identifies the episode)
    lower_bound: np.ndarray  # int64 (E,) min over agents of the BFS distance at the start
    summary: dict[str, Any] = field(init=False)

    def __post_init__(self) -> None:
        ok = self.found
        n = len(ok)
        self.summary = {
            "policy": self.policy,
            "episodes": n,
            "seed": self.seed,
            "batch": self.batch,
            "success_rate": float(ok.mean()) if n else math.nan,
            "success_ci": list(wilson_interval(int(ok.sum()), n)),
            "time_mean": _mean(self.time),
            "time_ci": _clipped(t_interval(self.time), 1.0),
            "cost_mean": _mean(self.cost),
            "cost_ci": _clipped(t_interval(self.cost), 0.0),
            "time_mean_success": _mean(self.time[ok]),
            "time_success_ci": _clipped(t_interval(self.time[ok]), 1.0),
            "cost_mean_success": _mean(self.cost[ok]),
            "cost_success_ci": _clipped(t_interval(self.cost[ok]), 0.0),
            "lower_bound_mean": _mean(self.lower_bound),
        }

    @property
    def episodes(self) -> int:
        return len(self.found)

    @property
    def success_rate(self) -> float:
        return self.summary["success_rate"]

    @property
    def time_mean(self) -> float:
        return self.summary["time_mean"]

    @property
    def cost_mean(self) -> float:
        return self.summary["cost_mean"]

    def to_dict(self, per_episode: bool = False) -> dict[str, Any]:
        """JSON-able summary (NaN -> None), optionally with the per-episode arrays."""
        out = {k: _json_number(v) for k, v in self.summary.items()}
        out["env"] = self.spec.to_dict()
        if per_episode:
            for name in ("found", "time", "cost", "target", "lower_bound"):
                out[name] = getattr(self, name).tolist()
        return out


def _json_number(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, list):
        return [_json_number(x) for x in v]
    return v


def chunk_seed(seed: int, chunk: int) -> int:
    """Seed of the chunk-th block of episodes (independent streams per chunk)."""
    return int(np.random.SeedSequence([seed, chunk]).generate_state(1, np.uint64)[0])


def evaluate(
    policy,
    env_spec: EnvSpec,
    episodes: int,
    seed: int = 0,
    batch: int | None = None,
    name: str | None = None,
) -> EvalReport:
    """Run ``episodes`` seeded episodes of ``policy`` (``reset(env)`` / ``act(env)``)."""
    if not 1 <= episodes <= MAX_EPISODES:
        raise ValueError(f"episodes must be in 1..{MAX_EPISODES:,}, got {episodes:,}")
    batch = default_batch(env_spec, episodes) if batch is None else int(batch)
    if batch < 1:
        raise ValueError(f"batch must be >= 1, got {batch}")
    sizes = [min(batch, episodes - start) for start in range(0, episodes, batch)]
    together = max(1, STEP_ENVS // batch) if getattr(policy, "rows_independent", True) else 1
    found, time, cost, target, bound = [], [], [], [], []
    for first in range(0, len(sizes), together):
        blocks = [(chunk_seed(seed, c), sizes[c])
                  for c in range(first, min(first + together, len(sizes)))]
        B = sum(size for _, size in blocks)
        env = TargetLocalizationEnv(env_spec, num_envs=B, autoreset=False, blocks=blocks)
        target.append(env.target.copy())
        bound.append(np.take_along_axis(env.dist, env.pos, axis=1).min(axis=1).astype(np.int64))
        f = np.zeros(B, dtype=bool)
        length = np.zeros(B, dtype=np.int64)
        moves = np.zeros(B, dtype=np.int64)
        policy.reset(env)
        for _ in range(env_spec.max_steps):
            result = env.step(policy.act(env))
            if result.episode is not None:
                idx = result.episode.index
                f[idx] = result.episode.found
                length[idx] = result.episode.length
                moves[idx] = result.episode.cost
            if env.done:
                break
        if not env.done:
            raise RuntimeError("environment did not end its episodes within max_steps")
        found.append(f)
        time.append(length)
        cost.append(moves)
    return EvalReport(
        policy=name or getattr(policy, "name", type(policy).__name__),
        spec=env_spec,
        seed=seed,
        batch=batch,
        found=np.concatenate(found),
        time=np.concatenate(time),
        cost=np.concatenate(cost),
        target=np.concatenate(target),
        lower_bound=np.concatenate(bound),
    )


@dataclass
class Comparison:
    """Ratios of a policy's figures to the oracle's on the same episodes.

    ``time_ratio = mean time / mean oracle time`` and likewise for cost (ratios of means over
    all episodes, so 1.0 is the lower bound); 95% intervals by a paired bootstrap over episodes.
    """

    time_ratio: float
    time_ratio_ci: tuple[float, float]
    cost_ratio: float
    cost_ratio_ci: tuple[float, float]

    def to_dict(self) -> dict[str, Any]:
        return {
            "time_ratio": _json_number(self.time_ratio),
            "time_ratio_ci": _json_number(list(self.time_ratio_ci)),
            "cost_ratio": _json_number(self.cost_ratio),
            "cost_ratio_ci": _json_number(list(self.cost_ratio_ci)),
        }


BOOTSTRAP_CHUNK = 1 << 20
"""Resampled indices held at once by the paired bootstrap (8 MB)."""


def _ratio_ci(
    num: np.ndarray, den: np.ndarray, rng: np.random.Generator, draws: int
) -> tuple[float, float]:
    n = len(num)
    # in chunks of rows: (draws, n) indices at once took ~32 KB per episode (3.7 GB for 100k
    # episodes); the same stream of draws, row by row, gives the same means
    rows = max(1, BOOTSTRAP_CHUNK // max(n, 1))
    a, b = np.empty(draws), np.empty(draws)
    for start in range(0, draws, rows):
        idx = rng.integers(0, n, size=(min(rows, draws - start), n))
        a[start:start + len(idx)] = num[idx].mean(axis=1)
        b[start:start + len(idx)] = den[idx].mean(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = a / b
    r = r[np.isfinite(r)]
    if len(r) == 0:
        return (math.nan, math.nan)
    lo, hi = np.percentile(r, [2.5, 97.5])
    return (float(lo), float(hi))


def same_episodes(a: EvalReport, b: EvalReport) -> bool:
    """True if both reports ran the very same layouts (spec, count, targets, start distances)."""
    return (
        a.spec == b.spec
        and a.episodes == b.episodes
        and np.array_equal(a.target, b.target)
        and np.array_equal(a.lower_bound, b.lower_bound)
    )


def compare(report: EvalReport, oracle: EvalReport, draws: int = 2000, seed: int = 0) -> Comparison:
    """time/oracle_time and cost/oracle_cost on the very same episodes (raises if they differ)."""
    if not same_episodes(report, oracle):
        raise ValueError(
            f"{report.policy!r} and {oracle.policy!r} were not evaluated on the same episodes "
            "(use the same spec, episodes, seed and batch)"
        )
    rng = np.random.default_rng(seed)
    t, c = report.time.astype(np.float64), report.cost.astype(np.float64)
    ot, oc = oracle.time.astype(np.float64), oracle.cost.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        tr = float(t.mean() / ot.mean()) if ot.mean() > 0 else math.nan
        cr = float(c.mean() / oc.mean()) if oc.mean() > 0 else math.nan
    return Comparison(tr, _ratio_ci(t, ot, rng, draws), cr, _ratio_ci(c, oc, rng, draws))
