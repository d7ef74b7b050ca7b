"""MEDC against its benchmarks on the Ch. 4 walls setting (issue 10; thesis Fig. 4.9-4.11, 5.5-5.8).

For each task user (A3W2, A3W3: 3 agents, 2 or 3 walls, 30 x 30, 8 moves) and each seed, every
method trains for the same env-step budget of the task user:

  sparse       PPO on the sparse reward (Eq. 9, S = 50) alone
  sr           PPO on the shaped BFS reward (MDRL-SR, Eq. 8)
  dc           sparse + Demonstration Cloning with the first expert (Alg. 4.1, E = 0.2)
  medc         sparse + MEDC with all experts, roulette over their QoS (Alg. 5.1, R_E = 0.1)
  medc-anneal  medc with R_E moving linearly from 0.2 (Table 4.1's E) to 0 over the budget
               (medc.py ``rate_end``; ours): more guidance early, none at the end; other
               ends with ``--anneal START,END``
  medc-faulty  sparse + MEDC with only faulty experts: 5 random, 5 biased, 5 malicious
  medc-credit, medc-faulty-credit
               the same with the expert credit rule (medc.py, ``credit``: experts whose
               guided episodes run longer than the agents' own fade out)
  il           sparse + IL-assisted RL with the same experts (il.py: 20% behaviour cloning)
  medc-il      medc's RL stages with il's cloning stages (ours): does MEDC gain from also
               cloning the experts, as IL does, where it ties with FRL and IL?
  medc-mixed, medc-mixed-credit, il-mixed
               MEDC (plain, with the credit rule) and IL with the experts plus as many faulty
               ones (random, biased, malicious; Fig. 5.8: 3 of the 6 shared models are faulty)
  frl          sparse + FedAvg across the eight users A1W0 ... A3W3 (frl.py), seen from the task
  frl-mixed    frl where 3 of the 8 users (not the task user; drawn by the seed) are faulty:
               they send FedAvg random, biased and malicious weights (Fig. 5.8; frl.py)
  frl-random, frl-biased, frl-malicious
               frl with one faulty user of that kind alone (the user frl-mixed draws for it
               with the same seed): which of the three kinds does frl-mixed's damage?
  sparse-cae, sr-cae, medc-cae
               sparse / SR / MEDC with the walls CAE's embedding (``--cae DIR``, Fig. 4.2) in
               place of the learner's downsized wall maps (the experts keep their own inputs):
               does the embedding beat the maps?

Every run evaluates its greedy policy on the same 100 held-out episodes every few updates (the
curve) and at the end on ``--episodes`` held-out episodes (``zoo.HELDOUT_SEED``) next to the
oracle. Output: a table per task (final time / cost / success, mean over seeds with a 95% CI;
env steps to reach SR's final level), the experts themselves on the same episodes (the team
taking each one's first choice: what the guided learners are shown), the issue's target ratios,
and ``--png`` with the curves (episode length against env steps and against wall-clock, mean
over seeds, min-max band).

``--review K`` picks the experts as a requester would, without the held-out figures: each
candidate of ``--experts``, followed by the team, on ``--review-episodes`` episodes of their
own (``REVIEW_SEED``); the K shortest are kept, with equal QoS (MMC's K best-rated models).

Each finished run is cached as JSON under ``--out`` (``TASK-METHOD-sSEED-STEPS.json``), so an
interrupted benchmark re-runs only what is missing, and a killed run resumes from its last
checkpoint (every ``CHECKPOINT_EVERY`` updates, FRL rounds). ``--jobs N`` trains the missing runs
in N processes at once (each run uses one thread: one job per core); their figures are those of
the same runs in turn, their wall-clock is that of runs sharing the machine.

Usage: python benchmarks/medc/run.py --steps 1000000 --seeds 0,1,2
       [--tasks A3W2,A3W3] [--methods sparse,sr,dc,medc,medc-faulty,il,frl]
       [--grid 30] [--belief] [--experts train | DIR,DIR,...] [--expert-steps 1000000]
       [--frl-steps N]
       [--cae DIR] [--bonus S]
       [--qos 1,1,1 | --review K [--review-episodes 500]] [--rate R_E] [--anneal START,END]
       [--episodes 1000] [--eval-every 5] [--out runs/medc] [--png benchmarks/medc/curves.png]
       [--jobs 2]
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy: one BLAS thread (workers/__init__.py)

import argparse
import dataclasses
import json
import math
import re
import signal
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from workers.mdrl.baselines import OraclePolicy
from workers.mdrl.evaluate import evaluate, t_interval
from workers.mdrl.experts import FollowExpert, load_experts
from workers.mdrl.medc import THRESHOLD as PAPER_THRESHOLD
from workers.mdrl.medc import DemonstrationSelector
from workers.mdrl.presets import get_preset
from workers.mdrl.review import REVIEW_SEED
from workers.mdrl.train import RunConfig, Trainer
from workers.mdrl.zoo import HELDOUT_SEED

METHODS = ("sparse", "sr", "dc", "medc", "medc-anneal", "medc-faulty", "medc-credit",
           "medc-faulty-credit", "medc-mixed", "medc-mixed-credit",
           "il", "il-mixed", "medc-il", "frl", "frl-mixed", "frl-random", "frl-biased",
           "frl-malicious",
           "sparse-cae", "sr-cae", "medc-cae")
EXPERT_USERS = ("A1W0", "A1W3", "A2W2")
GUIDED = ("medc", "medc-anneal", "medc-credit", "medc-il")
"""The methods with proper experts whose speed and rivals the targets report."""
MIXED = ("medc-mixed", "medc-mixed-credit")
"""The MEDC methods with proper and faulty experts, compared with IL on the same ones."""
FRL_ONE_FAULTY = ("frl-random", "frl-biased", "frl-malicious")
FRL = ("frl", "frl-mixed", *FRL_ONE_FAULTY)
ANNEAL = (0.2, 0.0)
"""medc-anneal's R_E at the start and at the end of the budget (``--anneal START,END``)."""
CURVE_EPISODES = 100
CURVE_SEED = 1_000_003
BELIEF = False
"""--belief: the product presets of the 10 x 10 scale-down (``ch4-a{N}w{K}-{r}-10x10``: the
team's belief map and 5 x 5 windows) instead of the thesis observation scaled down."""
ROUTE = False
"""--route: the ``-route`` presets (belief map and walking-distance maps, observations.py) of
the Ch. 4 setting, scaled to --grid like the thesis presets."""
CAE: str | None = None
"""--cae: the walls CAE directory of the ``-cae`` methods (trained for the benchmark's grid)."""
BONUS: float | None = None
"""--bonus: S of Eq. 9 for every sparse-reward run (the presets: 50, Table 4.1)."""
HORIZON: int | None = None
"""--horizon: env steps per PPO update of every run instead of the presets' (short runs)."""
REACH = 1.05
"""A run "reaches" a level when its mean held-out episode length is within 5% of it."""
CHECKPOINT_EVERY = 10
"""Updates (IL) or rounds (FRL) between the checkpoints a killed run resumes from."""


def user_preset(user: str, reward: str, grid: int = 30) -> Any:
    """``thesis_preset`` with ``--bonus`` as S of the sparse reward (Eq. 9) and ``--horizon``
    as the steps per update, when given."""
    preset = thesis_preset(user, reward, grid)
    if HORIZON is not None:
        preset = dataclasses.replace(preset, ppo=dataclasses.replace(preset.ppo, horizon=HORIZON))
    if BONUS is None or reward != "sparse":
        return preset
    return dataclasses.replace(preset, env=dataclasses.replace(preset.env, sparse_bonus=BONUS))


def method_reward(method: str) -> str:
    """The reward a benchmark method trains on: SR's shaped Eq. 8, every other method the
    task's sparse Eq. 9 (the experts, not the reward, are what differs)."""
    return "sr" if method in ("sr", "sr-cae") else "sparse"


def thesis_preset(user: str, reward: str, grid: int = 30) -> Any:
    """The Ch. 4 preset of a thesis user name such as A3W2 (agents 3, walls 2), on a
    ``grid`` x ``grid`` map of 50 m cells (30 = the thesis; smaller grids are the same setting
    scaled down so that it trains on this CPU)."""
    m = re.fullmatch(r"A(\d+)W(\d+)", user)
    if not m:
        raise ValueError(f"user {user!r}: expected A<agents>W<walls>, e.g. A3W2")
    if BELIEF:
        if grid != 10:
            raise ValueError(f"--belief: the product presets are 10x10, not {grid}x{grid}")
        return get_preset(f"ch4-a{m[1]}w{m[2]}-{reward}-10x10")
    preset = get_preset(f"ch4-a{m[1]}w{m[2]}-{reward}" + ("-route" if ROUTE else ""))
    if grid == preset.env.rows:
        return preset
    if grid <= preset.observation.window:
        raise ValueError(f"--grid {grid}: must exceed the window w = {preset.observation.window}")
    env = dataclasses.replace(preset.env, rows=grid, cols=grid, area_m=(50.0 * grid, 50.0 * grid))
    return dataclasses.replace(preset, name=f"{preset.name}-{grid}x{grid}", env=env)


def train_experts(users: list[str], grid: int, steps: int, out: Path) -> list[str]:
    """The experts of the benchmark (shaped reward, seed 0), trained once and cached: the
    thesis' A1W0, A1W3, A2W2 semi-experts (free multi-agent, complex single-agent, ...)."""
    dirs = []
    for user in users:
        model = out / "experts" / f"{user}-{grid}x{grid}-{steps}" / "model"
        if not (model / "model.json").is_file():
            preset = user_preset(user, "sr", grid)
            run = RunConfig(seed=0, total_steps=steps, eval_every=0, eval_episodes=CURVE_EPISODES,
                            eval_seed=CURVE_SEED, checkpoint_every=0, tensorboard=False,
                            progress=False)
            trainer = Trainer(preset.env, preset.observation, preset.ppo, run, out=model.parent)
            trainer.train()
            print(f"expert {user}: {trainer.last_eval}", file=sys.stderr, flush=True)
        dirs.append(str(model))
    return dirs


def faulty_refs(good: str, actions: int) -> list[str]:
    """5 random, 5 biased (each always one move), 5 malicious (the worst-ranked valid action
    of a good expert) - the faulty experts of Sec. 5.4.1."""
    return (["random"] * 5 + [f"biased:{1 + i % (actions - 1)}" for i in range(5)]
            + [f"malicious:{good}"] * 5)


def mixed_refs(good: list[str], actions: int) -> list[str]:
    """The proper experts and as many faulty ones - random, biased, malicious in turn (the
    malicious one inverts the first good expert) - the setting of the thesis' Fig. 5.8, where
    3 of the 6 users sharing models have faulty ones."""
    kinds = ("random", f"biased:{actions - 1}", f"malicious:{good[0]}")
    return [*good, *(kinds[i % 3] for i in range(len(good)))]


def faulty_users(task: str, seed: int, actions: int, method: str = "frl-mixed"
                 ) -> dict[str, str]:
    """frl-mixed's 3 faulty users: random, biased (the last action, as ``mixed_refs``) and
    malicious, drawn among the users other than the task user by the run's seed; for
    ``frl-KIND`` only the one of that kind (the same user as in frl-mixed), plain frl none."""
    from workers.mdrl.frl import THESIS_USERS

    others = [u for u in THESIS_USERS if u != task]
    picked = np.random.default_rng(seed).choice(len(others), size=3, replace=False)
    kinds = ("random", f"biased:{actions - 1}", "malicious")
    mixed = {others[int(i)]: kind for i, kind in zip(picked, kinds, strict=True)}
    if method == "frl-mixed":
        return mixed
    return {u: k for u, k in mixed.items() if f"frl-{k.split(':')[0]}" == method}


def train_run(task: str, method: str, seed: int, steps: int, experts: list[str],
              qos: list[float], eval_every: int, out: Path, grid: int) -> dict[str, Any]:
    """Train one (task, method, seed) and return its curve and held-out figures."""
    preset = user_preset(task, method_reward(method), grid)
    env, obs, ppo = preset.env, preset.observation, preset.ppo
    if method.endswith("-cae"):
        from workers.mdrl.cae import load_cae_card

        if CAE is None:
            raise SystemExit(f"method {method}: give the walls CAE with --cae DIR")
        obs = dataclasses.replace(obs, walls_embedding=CAE,
                                  walls_embedding_size=int(load_cae_card(CAE)["embedding"]))
    run = RunConfig(seed=seed, total_steps=steps, eval_every=eval_every,
                    eval_episodes=CURVE_EPISODES, eval_seed=CURVE_SEED,
                    checkpoint_every=CHECKPOINT_EVERY, tensorboard=False, progress=False,
                    keep_best="time")
    if method in FRL:  # FRL counts evaluations and checkpoints in rounds of K updates
        k = FRL_LOCAL_UPDATES
        run = dataclasses.replace(run, eval_every=eval_every // k,
                                  checkpoint_every=max(1, CHECKPOINT_EVERY // k))
    run_dir = out / f"{task}-{grid}x{grid}-{method}-s{seed}-{steps}"
    resume = (run_dir / "checkpoint").is_dir()  # a killed run: go on from its checkpoint
    if run_dir.exists() and not resume:  # killed before its first checkpoint: start again
        for f in sorted(run_dir.rglob("*"), reverse=True):
            f.unlink() if f.is_file() else f.rmdir()
    start = time.perf_counter()
    if method in FRL:
        from workers.mdrl.frl import THESIS_USERS, FederatedTrainer

        if resume:
            trainer: Any = FederatedTrainer.resume(run_dir, run_overrides=run.to_dict())
        else:
            users = [(u, user_preset(u, "sparse", grid).env) for u in THESIS_USERS]
            faulty = faulty_users(task, seed, env.num_actions, method)
            trainer = FederatedTrainer(users, obs, ppo, run, target=task, out=run_dir,
                                       faulty=faulty, local_updates=FRL_LOCAL_UPDATES)
    elif method in ("il", "il-mixed", "medc-il"):
        from workers.mdrl.il import ImitationTrainer

        refs = mixed_refs(experts, env.num_actions) if method == "il-mixed" else experts
        loaded = load_experts(refs, env, seed)
        guide = None  # medc-il: MEDC steers the RL stages
        if method == "medc-il":
            guide = DemonstrationSelector(load_experts(experts, env, seed), qos or None,
                                          MEDC_RATE, seed=seed, threshold=THRESHOLD)
        if resume:  # refuses other experts than the checkpoint's (another --out for those)
            trainer = ImitationTrainer.resume(run_dir, run_overrides=run.to_dict(),
                                              selector=guide, experts=loaded,
                                              qos=None if refs is not experts else qos or None)
        else:
            trainer = ImitationTrainer(env, obs, ppo, run, out=run_dir, experts=loaded,
                                       qos=None if refs is not experts else qos or None,
                                       selector=guide)
    else:
        selector = None
        if method == "dc":
            selector = DemonstrationSelector(load_experts(experts[:1], env, seed), seed=seed,
                                             threshold=THRESHOLD)
        elif method in ("medc", "medc-credit", "medc-anneal", "medc-cae"):
            rate, rate_end = ANNEAL if method == "medc-anneal" else (MEDC_RATE, None)
            selector = DemonstrationSelector(load_experts(experts, env, seed), qos or None,
                                             rate, seed=seed, credit=method.endswith("-credit"),
                                             threshold=THRESHOLD, rate_end=rate_end)
        elif method in MIXED:
            selector = DemonstrationSelector(
                load_experts(mixed_refs(experts, env.num_actions), env, seed), seed=seed,
                credit=method.endswith("-credit"), threshold=THRESHOLD)
        elif method in ("medc-faulty", "medc-faulty-credit"):
            refs = faulty_refs(experts[0], env.num_actions)
            selector = DemonstrationSelector(load_experts(refs, env, seed), seed=seed,
                                             credit=method.endswith("-credit"),
                                             threshold=THRESHOLD)
        if resume:  # the selector's per-episode state comes back from the checkpoint
            trainer = Trainer.resume(run_dir, run_overrides=run.to_dict(), selector=selector)
        else:
            trainer = Trainer(env, obs, ppo, run, out=run_dir, selector=selector)
    before = trainer.elapsed  # training time of the killed run we resumed (0 if fresh)
    learner = trainer.trainer if method in FRL else trainer
    # a run resumed from a checkpoint written without the selection saw only part of its curve
    selected = not resume or learner.best is not None
    trainer.train()
    wall = time.perf_counter() - start + before
    result = {"task": task, "grid": grid, "method": method, "seed": seed,
              "bonus": float(env.sparse_bonus), "horizon": ppo.horizon,
              "steps": trainer.global_step,
              "wall_s": wall, "curve": read_curve(run_dir / "metrics.csv"),
              "experts": experts, "qos": qos,
              "heldout": heldout(learner.policy(), env)}
    if method in FRL:
        result["local_updates"] = trainer.local_updates
    if getattr(learner, "selector", None) is not None and hasattr(learner.selector, "card"):
        result["guidance"] = learner.selector.card()  # episodes, decisions, followed, agreed
    if selected and learner.best is not None:  # the policy of the curve's shortest time
        result["best"] = {"step": learner.best["global_step"],
                          "curve_time": learner.best["eval_time"],
                          "heldout": heldout(learner.policy(best=True), env)}
    return result


def read_curve(metrics: Path) -> list[dict[str, float]]:
    """(env steps, wall-clock, success, time, cost) at every evaluation of a run."""
    import csv

    points = []
    with metrics.open() as f:
        for row in csv.DictReader(f):
            if row.get("eval_time"):
                points.append({"step": int(row["global_step"]), "wall": float(row["wall_time"]),
                               "success": float(row["eval_success"]),
                               "time": float(row["eval_time"]),
                               "cost": float(row["eval_cost"])})
    return points


def heldout(policy: Any, env: Any, episodes: int | None = None,
            seed: int = HELDOUT_SEED) -> dict[str, Any]:
    episodes = episodes or HELDOUT_EPISODES
    test = dataclasses.replace(env, readings="poisson")
    s = evaluate(policy, test, episodes, seed=seed).summary
    oracle = evaluate(OraclePolicy(), test, episodes, seed=seed)
    return {"episodes": episodes, "success": s["success_rate"], "time": s["time_mean"],
            "time_ci": s["time_ci"], "cost": s["cost_mean"], "cost_ci": s["cost_ci"],
            "oracle_time": oracle.time_mean}


HELDOUT_EPISODES = 1000
THRESHOLD = PAPER_THRESHOLD
"""l of the DC / MEDC runs (``--threshold``)."""
MEDC_RATE: float | None = None
"""R_E of medc / medc-credit (--rate); None: the selector's default, Table 5.3's 0.1."""
FRL_LOCAL_UPDATES = 1
"""FedAvg every this many local PPO updates of each FRL user (``--frl-local-updates``)."""


def expert_figures(task: str, grid: int, experts: list[str], out: Path,
                   episodes: int | None = None, seed: int = HELDOUT_SEED,
                   tag: str = "expert") -> list[dict]:
    """Each expert followed by the task user's team (:class:`FollowExpert`) on the held-out
    episodes (or ``episodes`` of ``seed``): what the guided learners are shown, untrained on
    the task. Cached under ``out`` per task, grid, expert, environment, seed and episodes."""
    env = user_preset(task, "sparse", grid).env
    episodes = episodes or HELDOUT_EPISODES
    rows, key = [], repr(env)
    for i, ref in enumerate(experts):
        slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", ref).strip("_")[-60:]
        cached = out / f"{task}-{grid}x{grid}-{tag}{i}-{slug}-{episodes}.json"
        row = json.loads(cached.read_text()) if cached.is_file() else None
        if (row is None or row.get("env") != key or row.get("ref") != ref
                or row.get("seed", HELDOUT_SEED) != seed):
            row = {"ref": ref, "env": key, "seed": seed,
                   "heldout": heldout(FollowExpert(ref, i), env, episodes, seed)}
            cached.write_text(json.dumps(row))
        rows.append(row)
    return rows


# REVIEW_SEED (workers/mdrl/review.py) seeds the review episodes (``--review``): the
# requester's own trial of the candidate experts, apart from the held-out episodes
# (``HELDOUT_SEED``) and the curve's (``CURVE_SEED``); the worker's trial uses the same seed.


def review_experts(task: str, grid: int, experts: list[str], keep: int, episodes: int,
                   out: Path) -> tuple[list[str], list[dict]]:
    """The requester's review before buying (``--review K``): each candidate expert followed
    by the task's team on review episodes of its own (``REVIEW_SEED``), ranked by mean
    episode length (a failed episode counts the horizon, so failures weigh in as lost time;
    the figure the targets judge). The K best, in their given order, become the experts,
    with equal QoS: what MMC's allocation of the K best-rated models (Eq. 12) buys once the
    reviews rank the models so, chosen without the held-out figures. Returns (kept, rows)."""
    rows = expert_figures(task, grid, experts, out, episodes, REVIEW_SEED, "review")
    ranked = sorted(range(len(rows)), key=lambda i: rows[i]["heldout"]["time"])
    best = set(ranked[:keep])
    for i, row in enumerate(rows):
        row["kept"] = i in best
    return [ref for i, ref in enumerate(experts) if i in best], rows


def review_table(rows: list[dict], bonus: float) -> list[str]:
    """The review of ``--review``: what each candidate did on the review episodes."""
    if not rows:
        return []
    h = rows[0]["heldout"]
    lines = [f"\n### The review: candidate experts followed by the team on {h['episodes']} "
             f"review episodes (seed {rows[0]['seed']}, oracle {h['oracle_time']:.2f})",
             "| expert | kept | success | time (95% CI) | moving cost | Eq. 9 return |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        h = r["heldout"]
        lines.append(f"| {r['ref']} | {'yes' if r['kept'] else 'no'} | "
                     f"{100 * h['success']:.1f}% | {h['time']:.2f}{_ci(h['time_ci'])} | "
                     f"{h['cost']:.2f} | {eq9_return(h, bonus):.2f} |")
    return lines


# ---------------------------------------------------------------------------- analysis
def shared_steps(runs: list[dict]) -> list[int]:
    """The evaluation points (env steps) every run of ``runs`` has on its curve."""
    return sorted(set.intersection(*(set(p["step"] for p in r["curve"]) for r in runs)))


def mean_curve(runs: list[dict], key: str = "time") -> tuple[np.ndarray, np.ndarray]:
    """Steps and the mean over seeds of ``key`` at the evaluation points all runs share."""
    common = shared_steps(runs)
    vals = np.array([[next(p[key] for p in r["curve"] if p["step"] == s) for s in common]
                     for r in runs])
    return np.array(common), vals.mean(0)


def steps_to(runs: list[dict], level: float) -> float:
    """Env steps at which the seed-mean held-out episode length first gets within REACH of
    ``level`` (inf if it never does)."""
    steps, curve = mean_curve(runs)
    hit = np.flatnonzero(curve <= level * REACH)
    return float(steps[hit[0]]) if len(hit) else math.inf


def last_level(runs: list[dict]) -> float:
    """The final level of a method on its learning curve: the seed-mean episode length at the
    last evaluation point (the curve's episodes, so that ``steps_to`` compares like with like)."""
    return float(mean_curve(runs)[1][-1])


def final(runs: list[dict], key: str) -> tuple[float, tuple[float, float]]:
    """Mean over seeds of a held-out figure, with the t-interval over the seeds (the per-run
    interval for one seed), cut at 0: the figures (time, cost, rates) are never negative."""
    v = np.array([r["heldout"][key] for r in runs])
    ci = t_interval(v) if len(v) > 1 else tuple(runs[0]["heldout"].get(f"{key}_ci",
                                                                       (math.nan, math.nan)))
    lo, hi = (math.nan if x is None else float(x) for x in ci)
    return float(v.mean()), (lo if math.isnan(lo) else max(lo, 0.0), hi)


def eq9_return(heldout: dict, bonus: float) -> float:
    """The held-out undiscounted team return under Eq. 9: S * success - moving cost."""
    return bonus * heldout["success"] - heldout["cost"]


def sparse_return(runs: list[dict], bonus: float) -> tuple[float, tuple[float, float]]:
    """Mean over seeds of the held-out undiscounted team return under Eq. 9, S * success -
    moving cost (Eq. 9 is linear in both), with its t-interval over the seeds: the objective
    the sparse-reward methods optimise, which trades time for fewer moves."""
    v = np.array([eq9_return(r["heldout"], bonus) for r in runs])
    ci = t_interval(v) if len(v) > 1 else (math.nan, math.nan)
    return float(v.mean()), (float(ci[0]), float(ci[1]))


def report(results: list[dict], shown: dict[str, list[dict]] | None = None) -> str:
    """The tables and target lines per task; ``shown`` maps a task to its
    :func:`expert_figures`."""
    lines = []
    shown = shown or {}
    for task in dict.fromkeys(r["task"] for r in results):
        by = {m: [r for r in results if r["task"] == task and r["method"] == m]
              for m in METHODS}
        by = {m: rs for m, rs in by.items() if rs}
        sr_level = last_level(by["sr"]) if "sr" in by else math.nan
        oracle = next(iter(by.values()))[0]["heldout"]["oracle_time"]
        grid = next(iter(by.values()))[0]["grid"]
        bonus = float(user_preset(task, "sparse", grid).env.sparse_bonus)
        lines += [f"\n## {task} (oracle {oracle:.2f} steps; held-out "
                  f"{next(iter(by.values()))[0]['heldout']['episodes']} episodes)",
                  "| method | seeds | env steps | wall-clock | success | time (95% CI) | "
                  f"cost (95% CI) | Eq. 9 return (S = {bonus:g}) | time / oracle | "
                  "steps to SR's final curve level |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for m, rs in by.items():
            t, t_ci = final(rs, "time")
            c, c_ci = final(rs, "cost")
            reach = steps_to(rs, sr_level) if not math.isnan(sr_level) else math.nan
            g, g_ci = sparse_return(rs, bonus)
            lines.append(
                f"| {m} | {len(rs)} | {rs[0]['steps'] / 1e6:.2f}M | "
                f"{np.mean([r['wall_s'] for r in rs]) / 60:.1f} min | "
                f"{100 * np.mean([r['heldout']['success'] for r in rs]):.1f}% | "
                f"{t:.2f} [{t_ci[0]:.2f}, {t_ci[1]:.2f}] | {c:.2f} [{c_ci[0]:.2f}, {c_ci[1]:.2f}] "
                f"| {g:.2f}{_ci(g_ci)} | {t / oracle:.2f} | {_steps(reach)} |")
        lines += selected_table(by, bonus, oracle)
        lines += experts_table(shown.get(task, []), bonus, oracle)
        lines += targets(by, sr_level)
        lines += against_experts(by, shown.get(task, []), bonus)
    return "\n".join(lines)


def experts_table(rows: list[dict], bonus: float, oracle: float) -> list[str]:
    """The experts followed by the team on the same held-out episodes (not trained here)."""
    if not rows:
        return []
    out = ["", "The experts on the task (the team takes each one's best-ranked valid action; "
           "not trained on the task):", "| expert | success | time (95% CI) | cost (95% CI) | "
           f"Eq. 9 return (S = {bonus:g}) | time / oracle |", "|---|---|---|---|---|---|"]
    for r in rows:
        h = r["heldout"]
        out.append(f"| {r['ref']} | {100 * h['success']:.1f}% | {h['time']:.2f}{_ci(h['time_ci'])} "
                   f"| {h['cost']:.2f}{_ci(h['cost_ci'])} | "
                   f"{eq9_return(h, bonus):.2f} | {h['time'] / oracle:.2f} |")
    return out


def against_experts(by: dict[str, list[dict]], rows: list[dict], bonus: float) -> list[str]:
    """Each guided learner's final time and Eq. 9 return against the best of the experts it
    was shown (the shortest time, the highest return): does it learn what it is shown? The
    learners optimise the return, which charges the moves the experts' time costs."""
    if not rows:
        return []

    fast = min(rows, key=lambda r: r["heldout"]["time"])
    rich = max(rows, key=lambda r: eq9_return(r["heldout"], bonus))
    t, g = fast["heldout"]["time"], eq9_return(rich["heldout"], bonus)
    return [f"- {m} ends at {final(by[m], 'time')[0]:.2f} steps, "
            f"{final(by[m], 'time')[0] / t:.2f}x the fastest expert followed ({fast['ref']}: "
            f"{t:.2f}), Eq. 9 return {sparse_return(by[m], bonus)[0]:.2f} against the best "
            f"expert's {g:.2f} ({rich['ref']})" for m in (*GUIDED, "medc-cae", "il") if m in by]


def kept(runs: list[dict]) -> list[dict] | None:
    """The runs as their kept policies (RunConfig.keep_best: the shortest time on the curve's
    episodes), judged on the held-out ones; None if a run has none (cached before selection)."""
    if not all("best" in r for r in runs):
        return None
    return [{**r, "heldout": r["best"]["heldout"]} for r in runs]


def selected_table(by: dict[str, list[dict]], bonus: float, oracle: float) -> list[str]:
    """Each method's kept policy (model selection on the curve's 100 episodes, then judged on
    the held-out ones: a stopping rule that values time as the targets do)."""
    rows = []
    for m, rs in by.items():
        ks = kept(rs)
        if ks is None:
            continue
        t, t_ci = final(ks, "time")
        c, c_ci = final(ks, "cost")
        g, g_ci = sparse_return(ks, bonus)
        at = np.mean([r["best"]["step"] for r in rs])
        rows.append(f"| {m} | {len(rs)} | {at / 1e6:.2f}M | "
                    f"{100 * np.mean([r['heldout']['success'] for r in ks]):.1f}% | "
                    f"{t:.2f} [{t_ci[0]:.2f}, {t_ci[1]:.2f}] | "
                    f"{c:.2f} [{c_ci[0]:.2f}, {c_ci[1]:.2f}] | {g:.2f}{_ci(g_ci)} | "
                    f"{t / oracle:.2f} |")
    if not rows:
        return []
    return ["", "Kept policy (shortest mean time on the curve's episodes, judged on the held-out "
            "ones):", "| method | seeds | chosen at (mean) | success | time (95% CI) | "
            f"cost (95% CI) | Eq. 9 return (S = {bonus:g}) | time / oracle |",
            "|---|---|---|---|---|---|---|---|", *rows]


def targets(by: dict[str, list[dict]], sr_level: float) -> list[str]:
    """The issue's targets as measured ratios."""
    out = ["", "Targets:"]
    for medc in GUIDED:
        if medc in by:
            out += speed_targets(by, medc, sr_level)
    for faulty in ("medc-faulty", "medc-faulty-credit"):
        if {faulty, "sparse"} <= set(by):
            f, f_ci = final(by[faulty], "time")
            s, s_ci = final(by["sparse"], "time")
            out.append(f"- {faulty} {f:.2f} [{f_ci[0]:.2f}, {f_ci[1]:.2f}] vs sparse "
                       f"{s:.2f} [{s_ci[0]:.2f}, {s_ci[1]:.2f}] (target: not worse beyond the "
                       "seed noise)")
    for plain in ("sparse", "sr", "medc"):
        if {plain, f"{plain}-cae"} <= set(by):
            a, a_ci = final(by[f"{plain}-cae"], "time")
            b, b_ci = final(by[plain], "time")
            out.append(f"- {plain} with the walls CAE {a:.2f} [{a_ci[0]:.2f}, {a_ci[1]:.2f}] vs "
                       f"with the wall maps {b:.2f} [{b_ci[0]:.2f}, {b_ci[1]:.2f}]")
    rivals = ([(m, o) for m in GUIDED for o in ("frl", "il")]
              + [(m, o) for m in MIXED for o in ("il-mixed", "frl-mixed", *FRL_ONE_FAULTY)])
    for medc, other in rivals:
        if {medc, other} <= set(by):
            steps, m = mean_curve(by[medc])
            steps_o, o = mean_curve(by[other])
            shared = np.intersect1d(steps, steps_o)
            wins = int(sum(m[steps == s][0] < o[steps_o == s][0] for s in shared))
            out.append(f"- {medc} vs {other.upper()}: shorter mean episodes at {wins} of "
                       f"{len(shared)} shared evaluation points; final "
                       f"{final(by[medc], 'time')[0]:.2f} vs "
                       f"{final(by[other], 'time')[0]:.2f}")
            gap = curve_gap(by[medc], by[other])
            if gap is not None:
                d, (lo, hi), n, k = gap
                out.append(f"  along the curve ({k} points, {n} paired seeds): {other.upper()} "
                           f"- {medc} mean episode length {d:+.2f} [{lo:+.2f}, {hi:+.2f}]")
                seeds = sorted({r["seed"] for r in by[medc]} & {r["seed"] for r in by[other]})
                end = np.array([next(r["heldout"]["time"] for r in by[other] if r["seed"] == x)
                                - next(r["heldout"]["time"] for r in by[medc] if r["seed"] == x)
                                for x in seeds])
                lo, hi = t_interval(end)
                out.append(f"  held-out at the end, paired: {other.upper()} - {medc} "
                           f"{end.mean():+.2f} [{lo:+.2f}, {hi:+.2f}]")
            km, ko = kept(by[medc]), kept(by[other])
            if km and ko:
                (a, a_ci), (b, b_ci) = final(km, "time"), final(ko, "time")
                out.append(f"  kept policies: {a:.2f}{_ci(a_ci)} vs {b:.2f}{_ci(b_ci)}")
    return out


def curve_gap(runs: list[dict], others: list[dict]
              ) -> tuple[float, tuple[float, float], int, int] | None:
    """"At equal env steps" over the whole curve: per seed both methods ran, the mean over
    the evaluation points all those runs share of (other's - this one's) curve episode length,
    then the mean over seeds with its t-interval; with the number of seeds and points. A
    positive gap: ``runs`` had the shorter episodes on average at the same steps. None with
    fewer than two paired seeds."""
    mine, theirs = ({r["seed"]: r for r in rs} for rs in (runs, others))
    seeds = sorted(set(mine) & set(theirs))
    if len(seeds) < 2:
        return None
    common = shared_steps([mine[s] for s in seeds] + [theirs[s] for s in seeds])
    if not common:
        return None

    def at(r: dict) -> np.ndarray:
        by_step = {p["step"]: p["time"] for p in r["curve"]}
        return np.array([by_step[x] for x in common])

    gaps = np.array([(at(theirs[s]) - at(mine[s])).mean() for s in seeds])
    return float(gaps.mean()), t_interval(gaps), len(seeds), len(common)


def speed_targets(by: dict[str, list[dict]], medc: str, sr_level: float) -> list[str]:
    """How fast the guided method ``medc`` reaches SR's and sparse's final levels."""
    out = []
    if "sr" in by:
        a, b = steps_to(by[medc], sr_level), steps_to(by["sr"], sr_level)
        out.append(f"- {medc} reaches SR's final level ({sr_level:.2f}) in {_steps(a)} env "
                   f"steps, SR in {_steps(b)}: ratio {_ratio(a, b)} (target <= 1)")
    if "sparse" in by:
        own = last_level(by["sparse"])
        s = steps_to(by["sparse"], own)
        a = steps_to(by[medc], sr_level) if not math.isnan(sr_level) else math.nan
        out.append(f"- sparse alone reaches its own final level ({own:.2f}) in {_steps(s)}; "
                   f"{medc} reaches SR's in {_steps(a)}: ratio {_ratio(a, s)} (target <= 1/3)")
        b = steps_to(by[medc], own)
        out.append(f"- {medc} reaches sparse's final level in {_steps(b)}: {_ratio(b, s)} of "
                   "the steps sparse needs")
    return out


def _ci(ci: tuple[float, float]) -> str:
    return "" if math.isnan(ci[0]) else f" [{ci[0]:.2f}, {ci[1]:.2f}]"


def _steps(x: float) -> str:
    return "never" if math.isinf(x) else ("-" if math.isnan(x) else f"{x / 1e6:.2f}M")


def _ratio(a: float, b: float) -> str:
    if math.isnan(a) or math.isnan(b) or math.isinf(b):
        return "n/a"
    return "inf" if math.isinf(a) else f"{a / b:.2f}"


def plot(results: list[dict], path: Path) -> None:
    """Episode length against env steps and wall-clock per task (cf. Fig. 4.9, 5.5-5.8), and
    the moving cost against env steps (Eq. 9 trades one for the other)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = list(dict.fromkeys(r["task"] for r in results))
    fig, axes = plt.subplots(len(tasks), 3, figsize=(16, 4 * len(tasks)), squeeze=False)
    for row, task in zip(axes, tasks, strict=True):
        for m in METHODS:
            rs = [r for r in results if r["task"] == task and r["method"] == m]
            if not rs:
                continue
            steps, mean = mean_curve(rs)

            def per_seed(key: str, rs: list[dict] = rs, steps: np.ndarray = steps) -> np.ndarray:
                return np.array([[next(p[key] for p in r["curve"] if p["step"] == s)
                                  for s in steps] for r in rs])

            vals, cost, walls = per_seed("time"), per_seed("cost"), per_seed("wall").mean(0)
            for ax, x, y in ((row[0], steps / 1e6, vals), (row[1], walls / 60, vals),
                             (row[2], steps / 1e6, cost)):
                ax.plot(x, y.mean(0), label=m)
                ax.fill_between(x, y.min(0), y.max(0), alpha=0.15)
        row[0].set(title=f"{task}: episode length vs env steps", xlabel="env steps (M)",
                   ylabel="held-out episode length")
        row[1].set(title=f"{task}: episode length vs wall-clock", xlabel="minutes")
        row[2].set(title=f"{task}: moving cost vs env steps", xlabel="env steps (M)",
                   ylabel="held-out moving cost (agent moves)")
        row[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def run_in_processes(pending: list[tuple[str, str, int]], argv: list[str], jobs: int,
                     out: Path) -> None:
    """Train each pending (task, method, seed) in a process of its own, ``jobs`` at a time: this
    script with the same options narrowed to that run (``--train-only``: it trains and writes
    its JSON to the cache, no report), its output in ``out/logs``. A run that fails does not
    stop the others; the benchmark then stops naming every failed run and its log (killed
    runs resume from their checkpoints on the next call)."""
    logs = out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    live: set[subprocess.Popen] = set()
    failed: list[str] = []
    stopping = threading.Event()
    lock = threading.Lock()  # no run starts once stopping is set

    def one(run: tuple[str, str, int]) -> None:
        task, method, seed = run
        log = logs / f"{task}-{method}-s{seed}.log"
        cmd = [sys.executable, str(Path(__file__).resolve()), *argv, "--tasks", task,
               "--methods", method, "--seeds", str(seed), "--jobs", "1", "--train-only"]
        start = time.perf_counter()
        with lock:
            if stopping.is_set():
                return
            with log.open("w") as f:  # the child holds its own copy of the descriptor
                proc = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT)
            live.add(proc)
        print(f"{task} {method} seed {seed}: started, log {log}", file=sys.stderr, flush=True)
        rc = proc.wait()
        live.discard(proc)
        if rc == 0:
            print(f"{task} {method} seed {seed}: done in "
                  f"{(time.perf_counter() - start) / 60:.1f} min", file=sys.stderr, flush=True)
        elif not stopping.is_set():
            failed.append(f"{task} {method} seed {seed} (exit {rc}; log {log})")
            print(f"{task} {method} seed {seed}: FAILED with exit {rc}, log {log}",
                  file=sys.stderr, flush=True)

    def on_sigterm(signum: int, frame: Any) -> None:
        raise SystemExit(128 + signum)

    previous = signal.signal(signal.SIGTERM, on_sigterm)
    pool = ThreadPoolExecutor(max_workers=jobs)
    try:
        list(pool.map(one, pending))
    except BaseException:  # Ctrl-C or kill: stop the children too (they resume from their
        with lock:         # last checkpoints on the next call) before waiting for them
            stopping.set()
            for proc in list(live):
                proc.terminate()
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        signal.signal(signal.SIGTERM, previous)
    if failed:
        raise SystemExit(f"{len(failed)} of {len(pending)} run(s) failed: " + "; ".join(failed))


def main(argv: list[str] | None = None) -> int:
    global HELDOUT_EPISODES, THRESHOLD, BELIEF, ROUTE, CAE, BONUS, HORIZON, MEDC_RATE, ANNEAL
    global FRL_LOCAL_UPDATES
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--steps", type=int, default=1_000_000)
    p.add_argument("--seeds", default="0,1,2")
    p.add_argument("--tasks", default="A3W2,A3W3")
    p.add_argument("--methods", default=",".join(METHODS))
    p.add_argument("--grid", type=int, default=30, help="map side in 50 m cells (30 = thesis)")
    p.add_argument("--experts", default="train",
                   help="expert model dirs, comma-separated, or 'train' = train A1W0, A1W3 and "
                        "A2W2 on the shaped reward first (cached under --out/experts)")
    p.add_argument("--expert-steps", type=int, default=1_000_000)
    p.add_argument("--frl-steps", type=int, default=None,
                   help="budget of the frl runs (default --steps): FRL collects the eight users' "
                   "experience per step of the task user, ~8x the others' wall-clock; the MEDC vs "
                   "FRL comparison is then over the evaluation points both reach")
    p.add_argument("--frl-local-updates", type=int, default=1, metavar="K",
                   help="the frl methods average the users' weights every K local PPO updates "
                   "of each user (default 1: every update, the most communication; K must divide "
                   "--eval-every); runs are cached under --out: another --out for another K")
    p.add_argument("--qos", default="", help="QoS weight per expert (default equal)")
    p.add_argument("--review", type=int, default=None, metavar="K",
                   help="keep the K best of --experts by a review on the task (the team "
                   "following each one on --review-episodes episodes of their own, not the "
                   "held-out ones), with equal QoS; one task; give another --out")
    p.add_argument("--review-episodes", type=int, default=500, metavar="N")
    p.add_argument("--episodes", type=int, default=HELDOUT_EPISODES)
    p.add_argument("--eval-every", type=int, default=5)
    p.add_argument("--out", type=Path, default=Path("runs/medc"))
    p.add_argument("--png", type=Path, default=None)
    p.add_argument("--threshold", type=float, default=PAPER_THRESHOLD,
                   help="l of DC / MEDC (default 0.05, Tables 4.1 / 5.3); runs are cached "
                   "under --out, so give another --out for another l")
    p.add_argument("--rate", type=float, default=None,
                   help="R_E of medc and medc-credit (default 0.1, Table 5.3); runs are cached "
                   "under --out, so give another --out for another R_E")
    p.add_argument("--anneal", default=None, metavar="START,END",
                   help="R_E of medc-anneal at the start and the end of the budget (default "
                   "0.2,0: Table 4.1's E down to none); give another --out for another schedule")
    p.add_argument("--belief", action="store_true",
                   help="with --grid 10: the product presets ch4-a{N}w{K}-{r}-10x10 (belief "
                   "map, 5 x 5 windows) for every user; give another --out (runs are cached)")
    p.add_argument("--route", action="store_true",
                   help="the -route presets (belief and walking-distance maps) at --grid; give "
                   "another --out (runs are cached)")
    p.add_argument("--bonus", type=float, default=None,
                   help="S of the sparse reward (Eq. 9) instead of the presets' 50: how much "
                   "finding the source is worth against moving; give another --out")
    p.add_argument("--horizon", type=int, default=None, metavar="N",
                   help="env steps per PPO update instead of the presets' (e.g. short test "
                   "runs); give another --out")
    p.add_argument("--cae", default=None,
                   help="walls CAE directory for the -cae methods (drlaas cae train, same grid)")
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="train the runs not yet cached in N processes at once (default 1: in "
                   "turn, in this process); the same figures, but the wall-clock of runs "
                   "sharing the machine; each run's output goes to --out/logs")
    p.add_argument("--train-only", action="store_true", help=argparse.SUPPRESS)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = p.parse_args(argv)
    if args.jobs < 1:
        p.error(f"--jobs must be >= 1, got {args.jobs}")
    BELIEF = args.belief
    ROUTE = args.route
    if BELIEF and ROUTE:
        p.error("--belief (the 10 x 10 product presets) and --route exclude each other")
    CAE = args.cae
    if args.bonus is not None and not args.bonus > 0:
        p.error(f"--bonus must be > 0, got {args.bonus}")
    BONUS = args.bonus
    if args.horizon is not None and args.horizon < 1:
        p.error(f"--horizon must be >= 1, got {args.horizon}")
    HORIZON = args.horizon
    HELDOUT_EPISODES = args.episodes
    THRESHOLD = args.threshold
    if args.rate is not None and not 0.0 < args.rate <= 1.0:
        p.error(f"--rate must be in (0, 1], got {args.rate}")
    MEDC_RATE = args.rate
    if args.frl_local_updates < 1:
        p.error(f"--frl-local-updates must be >= 1, got {args.frl_local_updates}")
    FRL_LOCAL_UPDATES = args.frl_local_updates
    if args.eval_every % FRL_LOCAL_UPDATES:
        p.error(f"--frl-local-updates {FRL_LOCAL_UPDATES} must divide --eval-every "
                f"{args.eval_every}, so that FRL is evaluated at the others' env steps")
    if args.anneal is not None:
        try:
            start, end = (float(x) for x in args.anneal.split(","))
        except ValueError:
            p.error(f"--anneal: expected START,END (two rates), got {args.anneal!r}")
        if not (0.0 <= start <= 1.0 and 0.0 <= end <= 1.0):
            p.error(f"--anneal: rates must be in [0, 1], got {args.anneal!r}")
        ANNEAL = (start, end)
    methods = [m for m in args.methods.split(",") if m]
    bad = [m for m in methods if m not in METHODS]
    if bad:
        p.error(f"unknown methods {bad}; known: {', '.join(METHODS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.experts == "train":
        experts = train_experts(list(EXPERT_USERS), args.grid, args.expert_steps, args.out)
    else:
        experts = [e for e in args.experts.split(",") if e]
    qos = [float(q) for q in args.qos.split(",") if q]
    if qos and len(qos) != len(experts):
        p.error(f"--qos: {len(qos)} weight(s) for {len(experts)} expert(s)")
    seeds = [int(s) for s in args.seeds.split(",") if s]
    tasks = [t for t in args.tasks.split(",") if t]
    g = args.grid
    reviewed: list[dict] = []
    if args.review is not None:
        if len(tasks) != 1:
            p.error(f"--review ranks the experts on one task; got --tasks {args.tasks}")
        if not 1 <= args.review <= len(experts):
            p.error(f"--review must be in 1..{len(experts)} (the experts given), "
                    f"got {args.review}")
        if args.review_episodes < 1:
            p.error(f"--review-episodes must be >= 1, got {args.review_episodes}")
        if qos:
            p.error("--review gives the experts it keeps equal QoS: drop --qos")
        experts, reviewed = review_experts(tasks[0], g, experts, args.review,
                                           args.review_episodes, args.out)

    def budget(method: str) -> int:
        return args.frl_steps if method in FRL and args.frl_steps else args.steps

    def cache(task: str, method: str, seed: int) -> Path:
        return args.out / f"{task}-{g}x{g}-{method}-s{seed}-{budget(method)}.json"

    if args.jobs > 1:
        pending = [(t, m, s) for t in tasks for m in methods for s in seeds
                   if not cache(t, m, s).is_file()]
        run_in_processes(pending, argv, args.jobs, args.out)
    results = []
    for task in tasks:
        for method in methods:
            for seed in seeds:
                cached = cache(task, method, seed)
                if cached.is_file():
                    r = json.loads(cached.read_text())
                    preset = user_preset(task, method_reward(method), g)
                    bonus = float(preset.env.sparse_bonus)
                    if method_reward(method) == "sparse" and r.get("bonus", 50.0) != bonus:
                        raise SystemExit(f"{cached} was run with S = {r.get('bonus', 50.0):g}, "
                                         f"not {bonus:g}: give another --out")
                    horizon = preset.ppo.horizon
                    if r.get("horizon", horizon) != horizon:
                        raise SystemExit(f"{cached} was run with {r['horizon']} steps per "
                                         f"update, not {horizon}: give another --out")
                    if method in FRL and r.get("local_updates", 1) != FRL_LOCAL_UPDATES:
                        raise SystemExit(f"{cached} averaged every {r.get('local_updates', 1)} "
                                         f"local update(s), not {FRL_LOCAL_UPDATES}: give "
                                         f"another --out")
                else:
                    r = train_run(task, method, seed, budget(method), experts, qos,
                                  args.eval_every, args.out, args.grid)
                    cached.write_text(json.dumps(r))
                results.append(r)
                h = r["heldout"]
                print(f"{task} {method} seed {seed}: time {h['time']:.2f} cost {h['cost']:.2f} "
                      f"success {h['success']:.3f} ({r['wall_s'] / 60:.1f} min)",
                      file=sys.stderr, flush=True)
    if args.train_only:
        return 0
    frl_local = (f", frl averaging every {FRL_LOCAL_UPDATES} local updates"
                 if FRL_LOCAL_UPDATES > 1 else "")
    print(f"MEDC benchmark: Ch. 4 setting on {args.grid}x{args.grid} cells of 50 m"
          f"{' (product presets: belief map, w = 5)' if BELIEF else ''}"
          f"{' (-route presets: belief and walking-distance maps)' if ROUTE else ''}, "
          f"{args.steps} env steps of the task user per run"
          f"{f' (frl: {args.frl_steps})' if args.frl_steps else ''}"
          f"{frl_local}"
          f", seeds {args.seeds}, experts "
          f"{experts}; trained and evaluated on Poisson readings")
    guided = {"il", *GUIDED, "medc-cae"}
    shown = {t: expert_figures(t, args.grid, experts, args.out)
             for t in dict.fromkeys(r["task"] for r in results)
             if guided & {r["method"] for r in results if r["task"] == t}}
    print(report(results, shown))
    if reviewed:
        bonus = float(user_preset(tasks[0], "sparse", g).env.sparse_bonus)
        print("\n".join(review_table(reviewed, bonus)))
    if args.png:
        plot(results, args.png)
        print(f"\ncurves: {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
