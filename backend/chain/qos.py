"""Pure-Python reference of the recruitment QoS formulas and of greedy top-NW selection.

The Solidity contracts (UMC/TMC/MMC) implement the ``*_fixed`` functions of this module line
for line; property-based tests check that the contracts pick the same workers and models as
:func:`recruit_training`, :func:`recruit_sharing` and :func:`allocate_models`. Every formula
has a float version (the thesis as written, ``float`` in and out) and a fixed-point version
(``int`` in and out) whose distance to the float version is bounded below.

Equations (thesis ch. 5.3.1 and 7.5):
  * Eq. 10-11  owner / model reputation in the MMC: ``total review / allocation count``
  * Eq. 12-13  MMC model QoS: ``Rep_i * Rep_m / (1 + D_m)``, ``D_m`` weighted env distance
  * Eq. 16     expertise ``Exp = N / N_max``
  * Eq. 17-19  commitment ``CM = Ac/A``, completion ``CP = E/Ac``, reputation ``sqrt(CM*CP)``
  * Eq. 20     computational capability ``CC = (2/pi) atan(w1 * cores)``
  * Eq. 21     training QoS ``Exp * Rep * R * CC``
  * Eq. 22-23  model-sharing similarity ``S = sum w_n |F_n^m - F_n^T|`` and
               QoS ``Exp * Rep * R / (1 + S)``
  * 7.6        greedy top-NW recruitment under the constraints of 7.5.1 / 7.5.2

Fixed point
-----------
Reputations, ratings, expertise, CC, weights, distances and QoS values are unsigned integers
scaled by ``ONE = 1_000_000`` (1.0 == ONE). Counters, CPU cores, RAM (GB), GPU series codes,
domain codes and environment attributes are plain unsigned integers. Every division floors
(Solidity ``/`` on uint256); no intermediate is ever negative.

Input ranges (enforced here with ``ValueError``; the contracts should use the same types):
  * counters (assigned, accepted, completed, rating count, allocation count) < 2**64,
    with ``completed <= accepted <= assigned``; review sums <= count * REVIEW_MAX
  * cpu cores, RAM, GPU series, domain codes, environment attributes < 2**32
  * ``w1`` (Eq. 20 weight, scaled) in [1, MAX_W1] with MAX_W1 = 10**12 (w1 <= 1e6 unscaled)
  * environment weights (Eq. 13/22) <= ONE each, summing to exactly ONE; at most MAX_ENV_DIMS
    attributes
Largest intermediates, all far below 2**256 (~1.16e77):
  * Eq. 19: ``accepted * completed * ONE**2`` < 2**128 * 2**40 < 2**168
  * Eq. 20: ``w1 * cores`` < 2**72; ``ONE**2`` and ``c * t**k`` terms < 2**60
  * Eq. 21: ``Exp * Rep * R * CC`` <= ONE**4 = 1e24 < 2**80
  * Eq. 22: ``S`` <= ONE * 2**32 < 2**53; Eq. 23 denominator ``(ONE + S) * ONE`` < 2**73
So uint256 never overflows; uint128 would already suffice for every value stored.

Precision (fixed vs float, in [0, 1] units; checked by tests/contracts/test_qos_reference.py):
  * Eq. 10, 11, 16, 17, 18, 19, rating: floor of the exact value, error < 1e-6.
    Eq. 19 is computed as ``isqrt(accepted * completed * ONE**2 // (assigned * accepted))``:
    the floored square root of the exactly scaled product CM*CP (equal to
    ``isqrt(completed * ONE**2 // assigned)`` since ``accepted`` cancels), hence error < 1e-6
    instead of the ~4e-4 that multiplying two already-floored ratios can lose.
  * Eq. 20 (:func:`atan_fixed`): |error| <= ATAN_MAX_ERR = 1.2e-5 (measured max ~8.9e-6).
  * Eq. 21: <= ATAN_MAX_ERR + 4e-6 (three floored terms and one final floor).
  * Eq. 23 and Eq. 12: < 4e-6 (distances are exact; the denominator is >= 1).

Decisions where the thesis is vague (also in the issue report)
------------------------------------------------------------------
1. Counters are kept per (domain, task type) -- :class:`Counters`: ``assigned`` (A, offers
   made to the worker that count: an accepted offer when accepted; one declined or expired
   when its task ends, and only if some worker held a slot of it then; never while the task
   runs, nor for a task nobody held at its end), ``accepted`` (Ac,
   offers accepted within the acceptance window), ``completed`` (E, outcomes submitted before
   the deadline and then accepted, or paid unreviewed at close; also N in Eq. 16),
   ``rating_sum`` / ``rating_count`` (requester reviews; an accepted offer without outcome at
   close is rated 0); docs/chain.md, "Offers that count". For model sharing "assigned" is a
   model allocation offered to the owner, "accepted" the owner accepting to share,
   "completed" the model delivered.
2. Reviews are integers in [0, REVIEW_MAX] (REVIEW_MAX = 5 stars); the rating is their mean
   divided by REVIEW_MAX, i.e. in [0, 1].
3. New users start at 0.5: reputation is ONE/2 while ``assigned == 0`` and rating is ONE/2
   while ``rating_count == 0``; MMC reputations (Eq. 10-11) are ONE/2 while the allocation
   count is 0 (thesis line 1078). With ``assigned > 0`` and ``accepted == 0`` the commitment is
   0, so the reputation is 0 (CP is then undefined and irrelevant).
4. Eq. 16: N_max is the maximum N over the candidates that pass the constraints for this task
   (the "candidate workers"). If N_max == 0 nobody has experience yet and every candidate gets
   Exp = ONE/2 (same rule as 3), so the ranking falls back on Rep * R * CC.
5. Eq. 12 divides by D_m, which is 0 for an identical environment; like Eq. 23 we use
   ``1 + D_m`` (thesis: "+1 ... for smoothing"). The float version does the same.
6. Owner reputation in Eq. 10 uses the owner's totals over all their models (what the UMC
   ``User`` record accumulates); a review counts towards both the model and its owner.
7. Environment weights (Eq. 13/22) are scaled integers summing to exactly ONE; the default
   equal weights are ONE // d each with the remainder added to the first weight.
8. Candidates in model sharing (Eq. 22-23) and in the MMC (Eq. 12) are models, not workers:
   one owner may place several models in the same group. A model whose environment has a
   different number of attributes than the request is not eligible (not an error, so that
   one bad record cannot block an allocation on chain).
9. The constraint filter (7.5.1, 7.5.2) also requires the worker to be ``available`` (the
   UMC status); GPU series are integer codes, 0 meaning "no GPU", and the accepted list is
   set by the consortium admins (passed in the task here).
10. Ties: equal QoS -> lower index (earlier registration) wins, in greedy selection and in
    the "next best" after an expired offer (``exclude`` argument of :func:`greedy_top`).
11. Thresholds (min reputation, min rating) are compared in fixed point (``>=``), as on chain.
12. Candidate pools (issue 8, allocation that scales): the candidates of a domain are its
    *pool*, the first ``pool_size`` (UMC ``poolSize``, default :data:`POOL_SIZE`) available
    workers covering the domain in the order they last became available (registration order
    when nobody changed status) -- :func:`domain_pool`. Training recruitment ranks pool
    members only; model sharing and the MMC (Eq. 12) rank only models whose owner is a pool
    member of the model's domain. N_max (Eq. 16) is taken over the eligible pool members.
    Ties still go to the lower index (the lower worker / model id), whatever the pool order.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum

ONE = 1_000_000
"""Fixed-point scale: 1.0 == ONE."""
HALF = ONE // 2
"""Initial reputation / rating / expertise of a user with no history (decision 3)."""
REVIEW_MAX = 5
"""A review is an integer in [0, REVIEW_MAX]; rating = mean review / REVIEW_MAX (decision 2)."""
W1_DEFAULT = 100_000
"""Default Eq. 20 weight w1 = 0.1: CC(4 cores) ~ 0.24, CC(16) ~ 0.64, CC(64) ~ 0.90."""
MAX_COUNTER = 2**64 - 1
MAX_ATTR = 2**32 - 1
MAX_W1 = 10**12
MAX_ENV_DIMS = 12  # ModelsManager.MAX_ENV_DIMS: at most two storage words of a model
POOL_SIZE = 64
"""UMC.DEFAULT_POOL_SIZE: candidates per domain (decision 12)."""
ATAN_MAX_ERR = 1.2e-5
"""Bound on |atan_fixed(x)/ONE - (2/pi) atan(x/ONE)| for every x >= 0 (test: dense grid)."""
QOS_TRAINING_MAX_ERR = ATAN_MAX_ERR + 4 / ONE
QOS_SHARING_MAX_ERR = 4 / ONE
QOS_MODEL_MAX_ERR = 3 / ONE


class TaskType(IntEnum):
    """Task type K (Table 7.1): DRL training or model sharing."""

    TRAINING = 0
    SHARING = 1


# --------------------------------------------------------------------------------------------
# validation


def _check_uint(name: str, value: int, bound: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{name} must be an int, got {type(value).__name__}")
    if value < 0 or value > bound:
        raise ValueError(f"{name} must be in [0, {bound}], got {value}")


def _check_counts(assigned: int, accepted: int, completed: int) -> None:
    _check_uint("assigned", assigned, MAX_COUNTER)
    _check_uint("accepted", accepted, MAX_COUNTER)
    _check_uint("completed", completed, MAX_COUNTER)
    if not completed <= accepted <= assigned:
        raise ValueError(
            f"need completed <= accepted <= assigned, got {completed}, {accepted}, {assigned}"
        )


def _check_reviews(name: str, total: int, count: int) -> None:
    _check_uint(f"{name} count", count, MAX_COUNTER)
    _check_uint(f"{name} total", total, count * REVIEW_MAX)


# --------------------------------------------------------------------------------------------
# data model


@dataclass(frozen=True)
class Counters:
    """History of one worker in one (domain, task type) (decision 1)."""

    assigned: int = 0
    """A: offers made to the worker (Eq. 17)."""
    accepted: int = 0
    """Ac: offers accepted within the acceptance window (Eq. 17-18)."""
    completed: int = 0
    """E: outcomes delivered before the deadline (Eq. 18); also N of Eq. 16."""
    rating_sum: int = 0
    """Sum of requester reviews, each in [0, REVIEW_MAX]."""
    rating_count: int = 0
    """Number of reviews."""

    def __post_init__(self) -> None:
        _check_counts(self.assigned, self.accepted, self.completed)
        _check_reviews("rating", self.rating_sum, self.rating_count)


_NO_HISTORY = Counters()


@dataclass(frozen=True)
class Worker:
    """A registered worker W_j (Table 7.1, UMC Worker of Table 7.2)."""

    domains: frozenset[int]
    """Dom^W: domain codes the worker covers."""
    cpu_cores: int
    """N_CPU (Eq. 20)."""
    ram_gb: int
    """RAM capacity in GB."""
    gpu_series: int
    """GPU series code; 0 = no GPU (decision 9)."""
    counters: Mapping[tuple[int, TaskType], Counters] = field(default_factory=dict)
    """History per (domain, task type); missing keys mean no history."""
    available: bool = True
    """UMC status: only available workers are offered tasks."""

    def __post_init__(self) -> None:
        for d in self.domains:
            _check_uint("domain", d, MAX_ATTR)
        _check_uint("cpu_cores", self.cpu_cores, MAX_ATTR)
        _check_uint("ram_gb", self.ram_gb, MAX_ATTR)
        _check_uint("gpu_series", self.gpu_series, MAX_ATTR)

    def stats(self, domain: int, task_type: TaskType) -> Counters:
        return self.counters.get((domain, task_type), _NO_HISTORY)


@dataclass(frozen=True)
class TrainingTask:
    """Requirements of a DRL training task (7.5.1); thresholds are fixed point."""

    domain: int
    num_workers: int
    """NW: group size."""
    min_reputation: int = 0
    min_rating: int = 0
    min_cpu_cores: int = 0
    min_ram_gb: int = 0
    accepted_gpu_series: frozenset[int] = frozenset()
    """Admin-set list of accepted GPU series codes (7.5.1)."""

    def __post_init__(self) -> None:
        _check_uint("domain", self.domain, MAX_ATTR)
        _check_uint("num_workers", self.num_workers, MAX_ATTR)
        _check_uint("min_reputation", self.min_reputation, ONE)
        _check_uint("min_rating", self.min_rating, ONE)
        _check_uint("min_cpu_cores", self.min_cpu_cores, MAX_ATTR)
        _check_uint("min_ram_gb", self.min_ram_gb, MAX_ATTR)


@dataclass(frozen=True)
class Model:
    """A shared model (Table 5.2 / 7.4)."""

    owner: int
    """Index of the owner in the worker list."""
    domain: int
    env: tuple[int, ...]
    """Environment details F^m / E^m (e.g. agents, walls)."""
    alloc_count: int = 0
    """Times the model was allocated (Eq. 11)."""
    total_review: int = 0
    """Sum of reviews of this model, each in [0, REVIEW_MAX] (Eq. 11)."""

    def __post_init__(self) -> None:
        _check_uint("owner", self.owner, MAX_ATTR)
        _check_uint("domain", self.domain, MAX_ATTR)
        _check_env("env", self.env)
        _check_reviews("model review", self.total_review, self.alloc_count)


@dataclass(frozen=True)
class SharingTask:
    """Requirements of a model-sharing task (7.5.2); thresholds are fixed point."""

    domain: int
    num_workers: int
    """NW: number of models wanted."""
    env: tuple[int, ...]
    """F^T: requester's environment attributes."""
    min_reputation: int = 0
    min_rating: int = 0
    env_weights: tuple[int, ...] | None = None
    """w_n of Eq. 22 (scaled, sum ONE); None = equal weights."""

    def __post_init__(self) -> None:
        _check_uint("domain", self.domain, MAX_ATTR)
        _check_uint("num_workers", self.num_workers, MAX_ATTR)
        _check_uint("min_reputation", self.min_reputation, ONE)
        _check_uint("min_rating", self.min_rating, ONE)
        _check_env("env", self.env)
        if self.env_weights is not None:
            check_weights(self.env_weights, len(self.env))


@dataclass(frozen=True)
class ModelRequest:
    """MMC ``allocateModel`` requirements (5.3.1); thresholds are fixed point."""

    domain: int
    num_models: int
    env: tuple[int, ...]
    """E^r: requester's environment attributes."""
    min_model_reputation: int = 0
    min_owner_reputation: int = 0
    env_weights: tuple[int, ...] | None = None
    """w_i of Eq. 13 (scaled, sum ONE); None = equal weights."""

    def __post_init__(self) -> None:
        _check_uint("domain", self.domain, MAX_ATTR)
        _check_uint("num_models", self.num_models, MAX_ATTR)
        _check_uint("min_model_reputation", self.min_model_reputation, ONE)
        _check_uint("min_owner_reputation", self.min_owner_reputation, ONE)
        _check_env("env", self.env)
        if self.env_weights is not None:
            check_weights(self.env_weights, len(self.env))


def _check_env(name: str, env: Sequence[int]) -> None:
    if len(env) > MAX_ENV_DIMS:
        raise ValueError(f"{name} has {len(env)} attributes, at most {MAX_ENV_DIMS} allowed")
    for i, v in enumerate(env):
        _check_uint(f"{name}[{i}]", v, MAX_ATTR)


# --------------------------------------------------------------------------------------------
# Eq. 16: expertise


def expertise(n: int, n_max: int) -> float:
    """Eq. 16: Exp = N / N_max, N = tasks completed in the domain, N_max = max over candidates.

    N_max == 0 (no candidate has experience) gives 0.5 (decision 4).
    """
    if n > n_max:
        raise ValueError(f"n ({n}) must not exceed n_max ({n_max})")
    return 0.5 if n_max == 0 else n / n_max


def expertise_fixed(n: int, n_max: int) -> int:
    """Eq. 16 in fixed point: floor(N * ONE / N_max); HALF when N_max == 0."""
    _check_uint("n", n, MAX_COUNTER)
    _check_uint("n_max", n_max, MAX_COUNTER)
    if n > n_max:
        raise ValueError(f"n ({n}) must not exceed n_max ({n_max})")
    if n_max == 0:
        return HALF
    return n * ONE // n_max


# --------------------------------------------------------------------------------------------
# Eq. 17-19: commitment, completion, reputation


def commitment(assigned: int, accepted: int) -> float:
    """Eq. 17: CM = Ac / A (accepted over assigned offers); 0.5 with no offers yet."""
    return 0.5 if assigned == 0 else accepted / assigned


def completion(accepted: int, completed: int) -> float:
    """Eq. 18: CP = E / Ac (completed over accepted tasks); 0.5 with nothing accepted yet."""
    return 0.5 if accepted == 0 else completed / accepted


def reputation(assigned: int, accepted: int, completed: int) -> float:
    """Eq. 19: Rep = sqrt(CM * CP), the geometric mean of Eq. 17 and Eq. 18.

    A = assigned, Ac = accepted, E = completed. New worker (A == 0): 0.5. A > 0 and Ac == 0:
    0 (CM = 0). See decision 3.
    """
    _check_counts(assigned, accepted, completed)
    if assigned == 0:
        return 0.5
    if accepted == 0:
        return 0.0
    return math.sqrt(commitment(assigned, accepted) * completion(accepted, completed))


def commitment_fixed(assigned: int, accepted: int) -> int:
    """Eq. 17 in fixed point: floor(Ac * ONE / A); HALF with no offers yet."""
    _check_counts(assigned, accepted, 0)
    return HALF if assigned == 0 else accepted * ONE // assigned


def completion_fixed(accepted: int, completed: int) -> int:
    """Eq. 18 in fixed point: floor(E * ONE / Ac); HALF with nothing accepted yet."""
    _check_counts(accepted, accepted, completed)
    return HALF if accepted == 0 else completed * ONE // accepted


def reputation_fixed(assigned: int, accepted: int, completed: int) -> int:
    """Eq. 19 in fixed point: isqrt(floor(Ac * E * ONE**2 / (A * Ac))) = floor(sqrt(E/A) * ONE).

    The product CM * CP is scaled by ONE**2 exactly before the single floor, so the result is
    the floor of the exact reputation (error < 1e-6). On chain ``Ac`` cancels:
    ``Math.sqrt(completed * ONE * ONE / assigned)`` returns the same integer.
    """
    _check_counts(assigned, accepted, completed)
    if assigned == 0:
        return HALF
    if accepted == 0:
        return 0
    return math.isqrt(accepted * completed * ONE * ONE // (assigned * accepted))


# --------------------------------------------------------------------------------------------
# rating (7.5.1: mean review scaled to [0, 1])


def rating(rating_sum: int, rating_count: int) -> float:
    """R = mean review / REVIEW_MAX in [0, 1]; 0.5 with no review yet (decisions 2-3)."""
    _check_reviews("rating", rating_sum, rating_count)
    return 0.5 if rating_count == 0 else rating_sum / (rating_count * REVIEW_MAX)


def rating_fixed(rating_sum: int, rating_count: int) -> int:
    """Rating in fixed point: floor(sum * ONE / (count * REVIEW_MAX)); HALF with no review."""
    _check_reviews("rating", rating_sum, rating_count)
    return HALF if rating_count == 0 else rating_sum * ONE // (rating_count * REVIEW_MAX)


# --------------------------------------------------------------------------------------------
# Eq. 20: computational capability, (2/pi) atan


# Odd polynomial g(t) = t*(C1 - C3 t^2 + C5 t^4 - C7 t^6 + C9 t^8) ~ (2/pi) atan(t) on [0, 1],
# coefficients scaled by ONE, fitted for this module by iteratively reweighted least squares
# towards the minimax fit (polynomial alone: ~7.3e-6; with fixed-point rounding: see
# ATAN_MAX_ERR). The signs are explicit so that every term is a non-negative integer.
ATAN_C1 = 636_535
ATAN_C3 = 210_279
ATAN_C5 = 114_693
ATAN_C7 = 54_213
ATAN_C9 = 13_271


def _atan_unit_fixed(t: int) -> int:
    """(2/pi) atan(t / ONE) * ONE for t in [0, ONE]; positive and negative terms summed apart."""
    t2 = t * t // ONE
    t3 = t2 * t // ONE
    t5 = t3 * t2 // ONE
    t7 = t5 * t2 // ONE
    t9 = t7 * t2 // ONE
    pos = ATAN_C1 * t + ATAN_C5 * t5 + ATAN_C9 * t9
    neg = ATAN_C3 * t3 + ATAN_C7 * t7
    # pos >= neg for every t in [0, ONE] (the polynomial is >= 0 there; checked by the tests).
    return (pos - neg) // ONE


def atan_fixed(x: int) -> int:
    """(2/pi) * atan(x / ONE), scaled by ONE, using only +, -, *, // on non-negative ints.

    For x <= ONE an odd degree-9 polynomial; for x > ONE the identity
    atan(x) = pi/2 - atan(1/x), i.e. ``ONE - g(ONE**2 // x)``. Max absolute error vs
    (2/pi) math.atan over x in [0, inf): ATAN_MAX_ERR = 1.2e-5 in [0, 1] units (measured
    ~8.9e-6 on a dense grid by the tests). Input range: 0 <= x < 2**128.
    """
    _check_uint("x", x, 2**128 - 1)
    if x <= ONE:
        return _atan_unit_fixed(x)
    return ONE - _atan_unit_fixed(ONE * ONE // x)


def computational_capability(cpu_cores: int, w1: float = W1_DEFAULT / ONE) -> float:
    """Eq. 20: CC = (2/pi) atan(w1 * N_CPU); w1 > 0 sets how fast CC saturates with cores."""
    if w1 <= 0:
        raise ValueError(f"w1 must be > 0, got {w1}")
    return 2.0 / math.pi * math.atan(w1 * cpu_cores)


def computational_capability_fixed(cpu_cores: int, w1: int = W1_DEFAULT) -> int:
    """Eq. 20 in fixed point: atan_fixed(w1 * N_CPU), w1 scaled by ONE (in [1, MAX_W1])."""
    _check_uint("cpu_cores", cpu_cores, MAX_ATTR)
    _check_uint("w1", w1, MAX_W1)
    if w1 == 0:
        raise ValueError("w1 must be > 0")
    return atan_fixed(w1 * cpu_cores)


# --------------------------------------------------------------------------------------------
# Eq. 21: training QoS


def qos_training(exp: float, rep: float, rat: float, cc: float) -> float:
    """Eq. 21: QoS_Tr = Exp * Rep * R * CC (all in [0, 1])."""
    return exp * rep * rat * cc


def qos_training_fixed(exp: int, rep: int, rat: int, cc: int) -> int:
    """Eq. 21 in fixed point: floor(Exp * Rep * R * CC / ONE**3), one floor (<= 1e24 inside)."""
    for name, v in (("exp", exp), ("rep", rep), ("rating", rat), ("cc", cc)):
        _check_uint(name, v, ONE)
    return exp * rep * rat * cc // (ONE * ONE * ONE)


# --------------------------------------------------------------------------------------------
# Eq. 13 / 22: weighted environment distance


def default_weights(d: int) -> tuple[int, ...]:
    """Equal weights ONE // d, remainder on the first weight, summing to ONE (decision 7)."""
    _check_uint("d", d, MAX_ENV_DIMS)
    if d == 0:
        return ()
    w = ONE // d
    return (w + ONE - w * d,) + (w,) * (d - 1)


def check_weights(weights: Sequence[int], d: int) -> None:
    """Weights of Eq. 13/22: d scaled non-negative integers summing to exactly ONE."""
    if len(weights) != d:
        raise ValueError(f"need {d} environment weights, got {len(weights)}")
    for i, w in enumerate(weights):
        _check_uint(f"weights[{i}]", w, ONE)
    if d and sum(weights) != ONE:
        raise ValueError(f"environment weights must sum to ONE={ONE}, got {sum(weights)}")


def env_distance(
    f_model: Sequence[float], f_task: Sequence[float], weights: Sequence[float]
) -> float:
    """Eq. 13 / Eq. 22: S = sum_n w_n |F_n^m - F_n^T|, sum w_n = 1 (0 = same environment)."""
    if not len(f_model) == len(f_task) == len(weights):
        raise ValueError(
            f"length mismatch: model {len(f_model)}, task {len(f_task)}, weights {len(weights)}"
        )
    return sum(w * abs(a - b) for w, a, b in zip(weights, f_model, f_task, strict=True))


def env_distance_fixed(
    f_model: Sequence[int], f_task: Sequence[int], weights: Sequence[int]
) -> int:
    """Eq. 13 / Eq. 22 in fixed point: sum w_n * |F_n^m - F_n^T| with w scaled: exact."""
    _check_env("f_model", f_model)
    _check_env("f_task", f_task)
    if len(f_model) != len(f_task):
        raise ValueError(f"length mismatch: model {len(f_model)}, task {len(f_task)}")
    check_weights(weights, len(f_task))
    s = 0
    for w, a, b in zip(weights, f_model, f_task, strict=True):
        s += w * (a - b if a >= b else b - a)
    return s


# --------------------------------------------------------------------------------------------
# Eq. 23: model-sharing QoS


def qos_sharing(exp: float, rep: float, rat: float, s: float) -> float:
    """Eq. 23: QoS_MS = Exp * Rep * R / (1 + S), S from Eq. 22."""
    return exp * rep * rat / (1.0 + s)


def qos_sharing_fixed(exp: int, rep: int, rat: int, s: int) -> int:
    """Eq. 23 in fixed point: floor(Exp * Rep * R / ((ONE + S) * ONE)), S scaled, one floor."""
    for name, v in (("exp", exp), ("rep", rep), ("rating", rat)):
        _check_uint(name, v, ONE)
    _check_uint("s", s, ONE * MAX_ATTR)
    return exp * rep * rat // ((ONE + s) * ONE)


# --------------------------------------------------------------------------------------------
# Eq. 10-12: MMC reputations and model QoS


def mmc_reputation(total_review: int, alloc_count: int) -> float:
    """Eq. 10 (owner) / Eq. 11 (model): Rep = Total Review / Allocation Count.

    Reviews are in [0, REVIEW_MAX], so the value is divided by REVIEW_MAX to lie in [0, 1];
    0.5 before the first allocation (thesis line 1078).
    """
    _check_reviews("review", total_review, alloc_count)
    return 0.5 if alloc_count == 0 else total_review / (alloc_count * REVIEW_MAX)


def mmc_reputation_fixed(total_review: int, alloc_count: int) -> int:
    """Eq. 10 / 11 in fixed point: floor(total * ONE / (count * REVIEW_MAX)); HALF if count 0."""
    _check_reviews("review", total_review, alloc_count)
    return HALF if alloc_count == 0 else total_review * ONE // (alloc_count * REVIEW_MAX)


def qos_model(rep_owner: float, rep_model: float, d_m: float) -> float:
    """Eq. 12: QoS_m = Rep_i * Rep_m / (1 + D_m) (smoothed as Eq. 23, decision 5)."""
    return rep_owner * rep_model / (1.0 + d_m)


def qos_model_fixed(rep_owner: int, rep_model: int, d_m: int) -> int:
    """Eq. 12 in fixed point: floor(Rep_i * Rep_m / (ONE + D_m)), D_m scaled, one floor."""
    _check_uint("rep_owner", rep_owner, ONE)
    _check_uint("rep_model", rep_model, ONE)
    _check_uint("d_m", d_m, ONE * MAX_ATTR)
    return rep_owner * rep_model // (ONE + d_m)


# --------------------------------------------------------------------------------------------
# greedy top-NW (7.6)


def greedy_top(
    scores: Sequence[int] | Sequence[float],
    k: int,
    eligible: Sequence[bool] | None = None,
    exclude: frozenset[int] | set[int] = frozenset(),
) -> list[int]:
    """Indices of the k best eligible scores, best first; ties -> lower index first (7.6).

    One pass over the candidates keeping a sorted array of at most k entries (insertion), as
    the contracts do: O(N * k), no full sort. A later candidate enters only with a strictly
    higher score, so on equal scores the earlier registration stays ahead. ``exclude`` drops
    candidates (workers whose offer expired: the "next best" is the best of the rest).
    Fewer than k eligible candidates: all of them are returned.
    """
    if k < 0:
        raise ValueError(f"k must be >= 0, got {k}")
    if eligible is not None and len(eligible) != len(scores):
        raise ValueError(f"eligible has {len(eligible)} entries for {len(scores)} scores")
    top_idx: list[int] = [0] * k
    top_q: list = [0] * k
    count = 0
    if k == 0:
        return []
    for i, q in enumerate(scores):
        if (eligible is not None and not eligible[i]) or i in exclude:
            continue
        if count < k:
            pos = count
            count += 1
        elif q > top_q[k - 1]:
            pos = k - 1
        else:
            continue
        while pos > 0 and top_q[pos - 1] < q:
            top_q[pos] = top_q[pos - 1]
            top_idx[pos] = top_idx[pos - 1]
            pos -= 1
        top_q[pos] = q
        top_idx[pos] = i
    return top_idx[:count]


# --------------------------------------------------------------------------------------------
# constraints and full recruitment pipelines


def training_eligible(w: Worker, task: TrainingTask) -> bool:
    """Constraints of 7.5.1 (line 1505-1512), all in fixed point:

    Dom^T in Dom^W, Rep_Tr >= Rep_min, R_Tr >= R_min, N_CPU >= CR_CPU, N_RAM >= CR_RAM, GPU
    series in the accepted list; plus the worker is available (decision 9).
    """
    if not w.available or task.domain not in w.domains:
        return False
    if w.cpu_cores < task.min_cpu_cores or w.ram_gb < task.min_ram_gb:
        return False
    if w.gpu_series not in task.accepted_gpu_series:
        return False
    c = w.stats(task.domain, TaskType.TRAINING)
    if reputation_fixed(c.assigned, c.accepted, c.completed) < task.min_reputation:
        return False
    return rating_fixed(c.rating_sum, c.rating_count) >= task.min_rating


def domain_pool(
    workers: Sequence[Worker],
    domain: int,
    pool_size: int = POOL_SIZE,
    order: Sequence[int] | None = None,
) -> frozenset[int]:
    """Decision 12: indices of the workers in ``domain``'s candidate pool (UMC ``pool``).

    The first ``pool_size`` available workers covering ``domain`` in ``order``, the worker
    indices in the order they last became available (default: list order, i.e. registration
    order when no worker changed status since).
    """
    _check_uint("pool_size", pool_size, MAX_ATTR)
    seq = range(len(workers)) if order is None else order
    members = [i for i in seq if workers[i].available and domain in workers[i].domains]
    return frozenset(members[:pool_size])


def training_qos_all(
    workers: Sequence[Worker],
    task: TrainingTask,
    w1: int = W1_DEFAULT,
    pool: frozenset[int] | None = None,
) -> tuple[list[bool], list[int]]:
    """Eligibility and fixed-point Eq. 21 QoS of every worker (0 where not eligible).

    Only members of the domain's candidate ``pool`` are eligible (default: :func:`domain_pool`
    with the default size). Two passes, as on chain: N_max over eligible workers (Eq. 16),
    then the QoS.
    """
    if pool is None:
        pool = domain_pool(workers, task.domain)
    eligible = [i in pool and training_eligible(w, task) for i, w in enumerate(workers)]
    n_max = 0
    for w, ok in zip(workers, eligible, strict=True):
        if ok:
            n_max = max(n_max, w.stats(task.domain, TaskType.TRAINING).completed)
    qos = []
    for w, ok in zip(workers, eligible, strict=True):
        if not ok:
            qos.append(0)
            continue
        c = w.stats(task.domain, TaskType.TRAINING)
        qos.append(
            qos_training_fixed(
                expertise_fixed(c.completed, n_max),
                reputation_fixed(c.assigned, c.accepted, c.completed),
                rating_fixed(c.rating_sum, c.rating_count),
                computational_capability_fixed(w.cpu_cores, w1),
            )
        )
    return eligible, qos


def training_qos_float(
    workers: Sequence[Worker],
    task: TrainingTask,
    w1: float = W1_DEFAULT / ONE,
    pool: frozenset[int] | None = None,
) -> list[float]:
    """Float Eq. 16-21 QoS (thesis as written) of every worker eligible under the fixed filter."""
    if pool is None:
        pool = domain_pool(workers, task.domain)
    eligible = [i in pool and training_eligible(w, task) for i, w in enumerate(workers)]
    stats = [w.stats(task.domain, TaskType.TRAINING) for w in workers]
    n_max = max((c.completed for c, ok in zip(stats, eligible, strict=True) if ok), default=0)
    return [
        qos_training(
            expertise(c.completed, n_max),
            reputation(c.assigned, c.accepted, c.completed),
            rating(c.rating_sum, c.rating_count),
            computational_capability(w.cpu_cores, w1),
        )
        if ok
        else 0.0
        for w, c, ok in zip(workers, stats, eligible, strict=True)
    ]


def recruit_training(
    workers: Sequence[Worker],
    task: TrainingTask,
    w1: int = W1_DEFAULT,
    exclude: frozenset[int] | set[int] = frozenset(),
    pool: frozenset[int] | None = None,
) -> list[int]:
    """7.6: the NW eligible workers with the highest Eq. 21 QoS, best first (TMC.allocateTask).

    Candidates: the domain's ``pool`` (decision 12; default :func:`domain_pool`)."""
    eligible, qos = training_qos_all(workers, task, w1, pool)
    return greedy_top(qos, task.num_workers, eligible, exclude)


def sharing_eligible(m: Model, workers: Sequence[Worker], task: SharingTask) -> bool:
    """Constraints of 7.5.2: model and owner in Dom^T, Rep_MS >= Rep_min, R_MS >= R_min.

    Plus: owner available, same number of environment attributes (decisions 8-9).
    """
    if m.domain != task.domain or len(m.env) != len(task.env):
        return False
    if m.owner >= len(workers):
        raise ValueError(f"model owner {m.owner} is not a registered worker")
    w = workers[m.owner]
    if not w.available or task.domain not in w.domains:
        return False
    c = w.stats(task.domain, TaskType.SHARING)
    if reputation_fixed(c.assigned, c.accepted, c.completed) < task.min_reputation:
        return False
    return rating_fixed(c.rating_sum, c.rating_count) >= task.min_rating


def sharing_qos_all(
    models: Sequence[Model],
    workers: Sequence[Worker],
    task: SharingTask,
    pool: frozenset[int] | None = None,
) -> tuple[list[bool], list[int]]:
    """Eligibility and fixed-point Eq. 23 QoS of every model (0 where not eligible).

    Only models whose owner is in the domain's candidate ``pool`` are eligible (decision 12;
    default :func:`domain_pool`)."""
    weights = task.env_weights if task.env_weights is not None else default_weights(len(task.env))
    if pool is None:
        pool = domain_pool(workers, task.domain)
    eligible = [m.owner in pool and sharing_eligible(m, workers, task) for m in models]
    n_max = 0
    for m, ok in zip(models, eligible, strict=True):
        if ok:
            n_max = max(n_max, workers[m.owner].stats(task.domain, TaskType.SHARING).completed)
    qos = []
    for m, ok in zip(models, eligible, strict=True):
        if not ok:
            qos.append(0)
            continue
        c = workers[m.owner].stats(task.domain, TaskType.SHARING)
        qos.append(
            qos_sharing_fixed(
                expertise_fixed(c.completed, n_max),
                reputation_fixed(c.assigned, c.accepted, c.completed),
                rating_fixed(c.rating_sum, c.rating_count),
                env_distance_fixed(m.env, task.env, weights),
            )
        )
    return eligible, qos


def sharing_qos_float(
    models: Sequence[Model],
    workers: Sequence[Worker],
    task: SharingTask,
    pool: frozenset[int] | None = None,
) -> list[float]:
    """Float Eq. 22-23 QoS of every model eligible under the fixed filter (0.0 otherwise)."""
    weights = task.env_weights if task.env_weights is not None else default_weights(len(task.env))
    wf = [w / ONE for w in weights]
    eligible, _ = sharing_qos_all(models, workers, task, pool)
    stats = [workers[m.owner].stats(task.domain, TaskType.SHARING) for m in models]
    n_max = max((c.completed for c, ok in zip(stats, eligible, strict=True) if ok), default=0)
    return [
        qos_sharing(
            expertise(c.completed, n_max),
            reputation(c.assigned, c.accepted, c.completed),
            rating(c.rating_sum, c.rating_count),
            env_distance(m.env, task.env, wf),
        )
        if ok
        else 0.0
        for m, c, ok in zip(models, stats, eligible, strict=True)
    ]


def recruit_sharing(
    models: Sequence[Model],
    workers: Sequence[Worker],
    task: SharingTask,
    exclude: frozenset[int] | set[int] = frozenset(),
    pool: frozenset[int] | None = None,
) -> list[int]:
    """7.6 for model sharing: indices of the NW eligible models with the highest Eq. 23 QoS."""
    eligible, qos = sharing_qos_all(models, workers, task, pool)
    return greedy_top(qos, task.num_workers, eligible, exclude)


def owner_totals(models: Sequence[Model]) -> dict[int, tuple[int, int]]:
    """Per owner: (total review, allocation count) over all their models (Eq. 10, decision 6)."""
    tot: dict[int, tuple[int, int]] = {}
    for m in models:
        r, n = tot.get(m.owner, (0, 0))
        tot[m.owner] = (r + m.total_review, n + m.alloc_count)
    return tot


def model_qos_all(
    models: Sequence[Model], req: ModelRequest, pool: frozenset[int] | None = None
) -> tuple[list[bool], list[int]]:
    """Eligibility and fixed-point Eq. 12 QoS of every model for an MMC request.

    Eligible: same domain (application), same number of environment attributes,
    Rep_m >= min model reputation, Rep_i >= min owner reputation (5.3.1), and the owner in the
    domain's candidate ``pool`` (decision 12: :func:`domain_pool` of the owners; None = every
    owner is a pool member, for callers without worker records).
    """
    weights = req.env_weights if req.env_weights is not None else default_weights(len(req.env))
    owners = owner_totals(models)
    eligible, qos = [], []
    for m in models:
        rep_m = mmc_reputation_fixed(m.total_review, m.alloc_count)
        rep_i = mmc_reputation_fixed(*owners[m.owner])
        ok = (
            (pool is None or m.owner in pool)
            and m.domain == req.domain
            and len(m.env) == len(req.env)
            and rep_m >= req.min_model_reputation
            and rep_i >= req.min_owner_reputation
        )
        eligible.append(ok)
        qos.append(
            qos_model_fixed(rep_i, rep_m, env_distance_fixed(m.env, req.env, weights)) if ok else 0
        )
    return eligible, qos


def model_qos_float(
    models: Sequence[Model], req: ModelRequest, pool: frozenset[int] | None = None
) -> list[float]:
    """Float Eq. 10-13 QoS of every model eligible under the fixed filter (0.0 otherwise)."""
    weights = req.env_weights if req.env_weights is not None else default_weights(len(req.env))
    wf = [w / ONE for w in weights]
    owners = owner_totals(models)
    eligible, _ = model_qos_all(models, req, pool)
    return [
        qos_model(
            mmc_reputation(*owners[m.owner]),
            mmc_reputation(m.total_review, m.alloc_count),
            env_distance(m.env, req.env, wf),
        )
        if ok
        else 0.0
        for m, ok in zip(models, eligible, strict=True)
    ]


def allocate_models(
    models: Sequence[Model],
    req: ModelRequest,
    exclude: frozenset[int] | set[int] = frozenset(),
    pool: frozenset[int] | None = None,
) -> list[int]:
    """MMC ``allocateModel`` (5.3.1): indices of the best ``num_models`` models by Eq. 12
    among the models of the domain's pool owners (decision 12)."""
    eligible, qos = model_qos_all(models, req, pool)
    return greedy_top(qos, req.num_models, eligible, exclude)
