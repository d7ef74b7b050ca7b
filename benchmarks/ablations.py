"""Seeded ablations: what moves the final quality of a trained policy (issue 9).

Each row is one change against the thesis-faithful base (ODMTL, 3 agents, 10x10, I = 1e9,
w = 3, last reading per cell divided by the episode maximum, the fast PPO settings of
``presets.FAST_PPO``), trained for the same env-step budget and seeds, then evaluated greedily
on the same held-out episodes (``zoo.HELDOUT_SEED``) under the chosen reading model. Rows are
cumulative where the name says "+" (each adds to the row above it) and single changes
otherwise. Output: a markdown table (change, steps, wall-clock, success, time and cost with
95% CIs, ratio to the oracle), the one in docs/learning.md, plus a JSON file per run.

Usage: python benchmarks/ablations.py [--steps 300000] [--seeds 0] [--episodes 500]
       [--rows base,mean,...] [--readings poisson] [--out runs/ablations]
Re-running with the same arguments reproduces the table up to wall-clock (seeded runs).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from workers.mdrl.baselines import OraclePolicy
from workers.mdrl.evaluate import evaluate, t_interval
from workers.mdrl.observations import ObservationSpec
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.presets import FAST_PPO
from workers.mdrl.spec import EnvSpec
from workers.mdrl.train import RunConfig, Trainer
from workers.mdrl.zoo import HELDOUT_SEED

BASE_OBS = dict(kind="odmtl", window=3)
PRODUCT = dict(readings="mean", scale="fixed", belief=True)
#: name -> (description, observation changes, PPO changes)
ROWS: dict[str, tuple[str, dict, dict]] = {
    "base": ("thesis observations (w=3, last reading / episode max), fast PPO", {}, {}),
    "mean": ("+ per-cell mean of the readings", {"readings": "mean"}, {}),
    "fixed": ("+ fixed log scale", {"readings": "mean", "scale": "fixed"}, {}),
    "belief": ("+ belief map", PRODUCT, {}),
    "window5": ("+ w = 5 (the product preset)", {**PRODUCT, "window": 5}, {}),
    "belief-only": ("belief map alone on the thesis observations", {"belief": True}, {}),
    "full-critic": ("product preset, full critic", {**PRODUCT, "window": 5, "critic": "full"},
                    {}),
    "ent-0.003": ("product preset, entropy 0.003", {**PRODUCT, "window": 5},
                  {"ent_coef": 0.003}),
    "ent-0.03": ("product preset, entropy 0.03", {**PRODUCT, "window": 5}, {"ent_coef": 0.03}),
    "lr-anneal": ("product preset, linear lr anneal", {**PRODUCT, "window": 5},
                  {"anneal_lr": True}),
    "epochs-10": ("product preset, 10 epochs x 8 minibatches", {**PRODUCT, "window": 5},
                  {"update_epochs": 10, "num_minibatches": 8}),
}


def run_row(name: str, steps: int, seed: int, episodes: int, readings: str,
            out: Path) -> dict:
    desc, obs_changes, ppo_changes = ROWS[name]
    env = EnvSpec(agents=3, readings="poisson")  # training always on the product default
    obs = ObservationSpec(**{**BASE_OBS, **obs_changes})
    ppo = PPOConfig(**{**FAST_PPO, **ppo_changes})
    run = RunConfig(seed=seed, total_steps=steps, eval_every=0, eval_episodes=50,
                    checkpoint_every=0, tensorboard=False, progress=False)
    start = time.perf_counter()
    trainer = Trainer(env, obs, ppo, run, out=None)
    trainer.train()
    wall = time.perf_counter() - start
    test = dataclasses.replace(env, readings=readings)
    report = evaluate(trainer.policy(), test, episodes, seed=HELDOUT_SEED)
    oracle = evaluate(OraclePolicy(), test, episodes, seed=HELDOUT_SEED)
    s = report.summary
    result = {"row": name, "change": desc, "seed": seed, "steps": trainer.global_step,
              "wall_s": wall, "readings": readings, "success": s["success_rate"],
              "time": s["time_mean"], "time_ci": s["time_ci"], "cost": s["cost_mean"],
              "cost_ci": s["cost_ci"], "oracle_time": oracle.time_mean}
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}-s{seed}-{steps}-{readings}.json").write_text(json.dumps(result))
    return result


def table(results: list[dict]) -> str:
    """One markdown row per ablation row; with several seeds, the mean over seeds and a
    Student-t 95% CI over the seed means (the per-run CI otherwise)."""
    lines = ["| change | steps | wall-clock | success | time (95% CI) | cost (95% CI) | "
             "time / oracle |", "|---|---|---|---|---|---|---|"]
    for name in dict.fromkeys(r["row"] for r in results):
        rs = [r for r in results if r["row"] == name]
        t = np.array([r["time"] for r in rs])
        c = np.array([r["cost"] for r in rs])
        if len(rs) > 1:
            t_ci, c_ci = t_interval(t), t_interval(c)
        else:
            t_ci, c_ci = rs[0]["time_ci"], rs[0]["cost_ci"]
        seeds = f" ({len(rs)} seeds)" if len(rs) > 1 else ""
        lines.append(
            f"| {rs[0]['change']}{seeds} | {rs[0]['steps'] / 1e6:.2f}M | "
            f"{np.mean([r['wall_s'] for r in rs]) / 60:.1f} min | "
            f"{100 * np.mean([r['success'] for r in rs]):.1f}% | "
            f"{t.mean():.2f} [{t_ci[0]:.2f}, {t_ci[1]:.2f}] | "
            f"{c.mean():.2f} [{c_ci[0]:.2f}, {c_ci[1]:.2f}] | "
            f"{t.mean() / rs[0]['oracle_time']:.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=300_000)
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--episodes", type=int, default=500)
    parser.add_argument("--rows", default=",".join(ROWS))
    parser.add_argument("--readings", choices=("poisson", "expected"), default="poisson")
    parser.add_argument("--out", type=Path, default=Path("runs/ablations"))
    args = parser.parse_args(argv)
    rows = [r for r in args.rows.split(",") if r]
    unknown = [r for r in rows if r not in ROWS]
    if unknown:
        parser.error(f"unknown rows {unknown}; known: {', '.join(ROWS)}")
    seeds = [int(s) for s in args.seeds.split(",") if s]
    results = []
    for name in rows:
        for seed in seeds:
            cached = args.out / f"{name}-s{seed}-{args.steps}-{args.readings}.json"
            r = (json.loads(cached.read_text()) if cached.is_file()
                 else run_row(name, args.steps, seed, args.episodes, args.readings, args.out))
            results.append(r)
            print(f"{name} seed {seed}: time {r['time']:.2f} cost {r['cost']:.2f} "
                  f"({r['wall_s'] / 60:.1f} min)", file=sys.stderr, flush=True)
    print(f"ODMTL, 3 agents, 10x10, I = 1e9, trained on Poisson readings; {args.episodes} "
          f"held-out episodes ({args.readings} readings), seeds {args.seeds}")
    print(table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
