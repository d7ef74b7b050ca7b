"""Metaheuristic group recruitment (GA, PSO, ACO) for the thesis Fig. 7.9 comparison.

Each method picks ``k`` distinct workers maximising the group QoS (mean QoS of the group)
from a QoS vector; they are the benchmarks the greedy top-NW selection of 7.6 is compared
against. Written for this project with numpy; settings are dataclasses so the benchmark can
print them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def group_qos(qos: np.ndarray, idx: np.ndarray) -> float:
    """Objective of every method: the mean QoS of the selected workers ("group average QoS")."""
    return float(qos[idx].mean())


def _check(qos: np.ndarray, k: int) -> None:
    if qos.ndim != 1:
        raise ValueError(f"qos must be a 1-D array, got shape {qos.shape}")
    if not 1 <= k <= qos.size:
        raise ValueError(f"group size k must be in [1, {qos.size}], got {k}")


# ------------------------------------------------------------------------------ GA


@dataclass(frozen=True)
class GAConfig:
    population: int = 50
    """Individuals; each one is a set of k distinct workers."""
    generations: int = 100
    tournament: int = 3
    """Tournament size of parent selection."""
    elite: int = 2
    """Best individuals copied unchanged into the next generation."""
    mutation: float = 0.2
    """Probability, per gene, of swapping the worker for a random one outside the group."""


def ga_select(qos: np.ndarray, k: int, rng: np.random.Generator, cfg: GAConfig = GAConfig()):
    """Genetic algorithm: tournament selection, set-union crossover (the child draws k workers
    from the union of both parents), swap mutation, elitism."""
    _check(qos, k)
    n = qos.size
    pop = np.argsort(rng.random((cfg.population, n)), axis=1)[:, :k]
    fit = qos[pop].mean(axis=1)
    for _ in range(cfg.generations):
        order = np.argsort(-fit)
        new = [pop[i] for i in order[: cfg.elite]]
        contenders = rng.integers(
            0, cfg.population, size=(cfg.population - cfg.elite, 2, cfg.tournament)
        )
        winners = contenders[
            np.arange(contenders.shape[0])[:, None],
            np.arange(2)[None, :],
            np.argmax(fit[contenders], axis=2),
        ]
        for a, b in winners:
            union = np.union1d(pop[a], pop[b])
            child = rng.choice(union, size=k, replace=False)
            members = set(child.tolist())
            for g in np.flatnonzero(rng.random(k) < cfg.mutation):
                w = int(rng.integers(n))
                while w in members:
                    w = int(rng.integers(n))
                members.discard(int(child[g]))
                members.add(w)
                child[g] = w
            new.append(child)
        pop = np.stack(new)
        fit = qos[pop].mean(axis=1)
    return pop[int(np.argmax(fit))]


# ------------------------------------------------------------------------------ PSO


@dataclass(frozen=True)
class PSOConfig:
    particles: int = 30
    iterations: int = 100
    inertia: float = 0.7
    c_personal: float = 1.5
    c_global: float = 1.5
    v_max: float = 0.2
    """Velocity clip; positions live in [0, 1]."""


def _decode(x: np.ndarray, k: int) -> np.ndarray:
    """Random-key decoding: a particle selects the k workers with the largest keys."""
    return np.argpartition(-x, k - 1, axis=-1)[..., :k]


def pso_select(qos: np.ndarray, k: int, rng: np.random.Generator, cfg: PSOConfig = PSOConfig()):
    """Particle swarm optimisation over random keys (one key per worker, groups = top-k keys)."""
    _check(qos, k)
    n = qos.size
    x = rng.random((cfg.particles, n))
    v = np.zeros_like(x)
    fit = qos[_decode(x, k)].mean(axis=1)
    pbest, pfit = x.copy(), fit.copy()
    g = int(np.argmax(pfit))
    for _ in range(cfg.iterations):
        r1 = rng.random(x.shape)
        r2 = rng.random(x.shape)
        v = cfg.inertia * v + cfg.c_personal * r1 * (pbest - x) + cfg.c_global * r2 * (pbest[g] - x)
        np.clip(v, -cfg.v_max, cfg.v_max, out=v)
        x = np.clip(x + v, 0.0, 1.0)
        fit = qos[_decode(x, k)].mean(axis=1)
        better = fit > pfit
        pbest[better], pfit[better] = x[better], fit[better]
        g = int(np.argmax(pfit))
    return _decode(pbest[g], k)


# ------------------------------------------------------------------------------ ACO


@dataclass(frozen=True)
class ACOConfig:
    ants: int = 20
    iterations: int = 50
    alpha: float = 1.0
    """Pheromone exponent."""
    beta: float = 1.0
    """Heuristic (QoS) exponent."""
    evaporation: float = 0.1
    deposit: float = 1.0
    """Pheromone added per unit of the iteration-best group QoS on its workers."""


def aco_select(qos: np.ndarray, k: int, rng: np.random.Generator, cfg: ACOConfig = ACOConfig()):
    """Ant colony optimisation: workers are nodes; an ant walks k distinct nodes, choosing the
    next with probability proportional to tau^alpha * QoS^beta; the iteration-best ant
    deposits pheromone on its workers after evaporation."""
    _check(qos, k)
    n = qos.size
    tau = np.ones(n)
    eta = (qos + 1e-9) ** cfg.beta
    best_idx, best_fit = None, -np.inf
    for _ in range(cfg.iterations):
        p = tau**cfg.alpha * eta
        p /= p.sum()
        it_idx, it_fit = None, -np.inf
        for _ant in range(cfg.ants):
            idx = rng.choice(n, size=k, replace=False, p=p)
            f = qos[idx].mean()
            if f > it_fit:
                it_idx, it_fit = idx, f
        tau *= 1.0 - cfg.evaporation
        tau[it_idx] += cfg.deposit * it_fit
        if it_fit > best_fit:
            best_idx, best_fit = it_idx, it_fit
    return best_idx
