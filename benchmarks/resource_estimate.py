"""The resource model's time figures against the clock (``workers/mdrl/resources.py``).

A worker accepts an offer, and a task is priced per worker-hour, on ``resources.estimate``;
the trainer's time budget holds the final greedy evaluation on ``final_evaluation_seconds``.
For a spread of specs (grid, window, agents, walls, belief and route maps), this prints the
estimated and the measured seconds of one PPO update (rollout + epochs) and of the job's
final evaluation (JOB_EVAL_EPISODES episodes of an untrained policy, which runs every episode
to ``max_steps``), and their ratio (measured / estimated: above 1, the model is optimistic).
The estimates are meant to refuse the absurd, not to plan capacity: a ratio within ~0.3-3 is
the aim. One training thread, one BLAS thread (``workers/__init__.py``); with
``--blas-threads 2`` numpy's OpenBLAS runs two, to show what that costs on a loaded machine.

Usage:
  python benchmarks/resource_estimate.py                  # ~2 min on this project's CPU
  python benchmarks/resource_estimate.py --max-steps 300 --blas-threads 2
"""

from __future__ import annotations

import argparse
import os
import sys

if __name__ == "__main__":  # before numpy loads: the BLAS threads asked for
    _threads = sys.argv[sys.argv.index("--blas-threads") + 1] if "--blas-threads" in sys.argv \
        else "1"
    for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[_var] = _threads

import statistics
import time

import torch

from workers.mdrl import resources
from workers.mdrl.train import Trainer
from workers.mdrl.trainingspec import TrainingSpec

CASES: list[tuple[str, dict, dict]] = [
    ("10x10, 3 agents, w = 3", {"rows": 10, "cols": 10, "agents": 3}, {}),
    ("20x20, 3 agents, w = 3", {"rows": 20, "cols": 20, "agents": 3}, {}),
    ("30x30, 3 agents, w = 3", {"rows": 30, "cols": 30, "agents": 3}, {}),
    ("30x30, 1 agent, w = 3", {"rows": 30, "cols": 30, "agents": 1}, {}),
    ("40x40, 3 agents, w = 3", {"rows": 40, "cols": 40, "agents": 3}, {}),
    ("30x30, 3 walls, w = 7", {"rows": 30, "cols": 30, "agents": 3, "moves": 8,
                               "walls": [3, 3]}, {"window": 7}),
    ("10x10, 1 wall, belief", {"rows": 10, "cols": 10, "agents": 3, "walls": [1, 1]},
     {"belief": True}),
    ("30x30, 3 walls, w = 7, belief + route (Ch. 4)",
     {"rows": 30, "cols": 30, "agents": 3, "moves": 8, "walls": [3, 3]},
     {"window": 7, "belief": True, "route": True, "readings": "mean", "scale": "fixed"}),
    ("6x6, 6 agents, CMTL (5**6 joint actions)", {"rows": 6, "cols": 6, "agents": 6},
     {"kind": "cmtl"}),
]


def measure(env: dict, obs: dict, max_steps: int, updates: int) -> dict[str, float]:
    spec = TrainingSpec.from_dict({
        "env": {**env, "max_steps": max_steps, "idle_limit": max_steps},
        "observation": obs, "algorithm": {"preset": "odmtl-3a-10x10"},
        "budget": {"steps": 1_000_000},
    })
    trainer = Trainer(spec.env, spec.observation, spec.ppo, spec.run_config())
    update_s = []
    for _ in range(updates + 1):  # the first update pays for compiling the kernels
        t0 = time.perf_counter()
        trainer.collect()
        trainer.update()
        update_s.append(time.perf_counter() - t0)
    trainer.evaluate()  # builds the evaluation's env geometry once, as training has
    t0 = time.perf_counter()
    trainer.evaluate()
    eval_s = time.perf_counter() - t0
    return {
        "update_est": resources.update_seconds(spec),
        "update": statistics.median(update_s[1:]),
        "eval_est": resources.final_evaluation_seconds(spec),
        "eval": eval_s,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-steps", type=int, default=200,
                    help="the specs' max_steps (the evaluation runs 100 episodes of it)")
    ap.add_argument("--updates", type=int, default=2, help="PPO updates timed per spec")
    ap.add_argument("--only", default=None, metavar="TEXT",
                    help="measure only the specs whose label contains TEXT")
    ap.add_argument("--blas-threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(1)
    print(f"BLAS threads {os.environ.get('OPENBLAS_NUM_THREADS')}, max_steps {args.max_steps}, "
          f"batch of the odmtl-3a-10x10 preset; seconds, ratio = measured / estimated")
    print(f"{'spec':48} {'update est':>10} {'measured':>9} {'ratio':>6}   "
          f"{'eval est':>8} {'measured':>9} {'ratio':>6}")
    ratios = []
    for label, env, obs in CASES:
        if args.only is not None and args.only not in label:
            continue
        m = measure(env, obs, args.max_steps, args.updates)
        r_up, r_ev = m["update"] / m["update_est"], m["eval"] / m["eval_est"]
        ratios += [r_up, r_ev]
        print(f"{label:48} {m['update_est']:10.2f} {m['update']:9.2f} {r_up:6.2f}   "
              f"{m['eval_est']:8.2f} {m['eval']:9.2f} {r_ev:6.2f}", flush=True)
    print(f"ratios: min {min(ratios):.2f}, median {statistics.median(ratios):.2f}, "
          f"max {max(ratios):.2f}")


if __name__ == "__main__":
    main()
