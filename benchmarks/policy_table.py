"""The zoo against thesis Tables 3.5 / 3.6 and the uniform, Bayesian and oracle searchers.

One table per block, every policy of a block on the very same seeded episodes
(``workers.mdrl.evaluate``), so the ratios to the oracle (time = cost = min BFS distance, the
lower bound) are paired. Each block runs under both reading models: ``expected`` (noise-free
counts, what the thesis author's code does: the comparison with the thesis tables) and
``poisson`` (the product default). Thesis rows are published means over other random draws of
the same set-up, so their ratios (marked ~) use our oracle's mean.

Blocks:
  * Table 3.5: 10x10, I = 1e9, team sizes 1, 2, 3, 4, 10: every zoo model of that team size
    (``models/{odmtl,dmtl,cmtl}-Na``) with its training steps and wall-clock, the thesis'
    per-model minima of Table 3.5.
  * Table 3.6: 3 agents, I = 1e8 ... 1e9: the 3-agent zoo models against thesis ODMTL / DDQN.
  * Held-out configurations for the generalist (``models/odmtl-generalist``, if present):
    9x13, 6 agents, I = 3e8, walls 1-3 — none of which it trained on.

Usage: python benchmarks/policy_table.py [--models models] [--episodes 1000] [--seed 0]
       [--teams 1,2,3,4,10] [--intensities 1e8,2.5e8,5e8,7.5e8,1e9] [--json]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from workers.mdrl.baselines import make_baseline
from workers.mdrl.evaluate import EvalReport, compare, evaluate
from workers.mdrl.spec import EnvSpec, IntensitySpec

#: Table 3.5 (line 587-598): lowest mean (time, cost) per team size and model.
TABLE_3_5 = {
    1: {"CMTL": (9.8, 9.8), "DMTL": (9.0, 9.0), "ODMTL": (8.3, 8.3)},
    2: {"CMTL": (7.7, 13.1), "DMTL": (5.5, 7.8), "ODMTL": (5.7, 8.1)},
    3: {"DMTL": (4.7, 5.1), "ODMTL": (5.8, 6.3)},
    4: {"DMTL": (4.5, 4.8), "ODMTL": (5.5, 5.8)},
    10: {"DMTL": (2.8, 6.2), "ODMTL": (3.2, 6.8)},
}
#: Table 3.6: (time, cost) per target strength; DDQN is one agent, so time = cost.
TABLE_3_6 = {
    "ODMTL T3.6": {1e8: (11.27, 13.3), 2.5e8: (9.27, 10.99), 5e8: (8.61, 9.76),
                            7.5e8: (7.71, 9.38), 1e9: (7.54, 8.78)},
    "DDQN 1 agent T3.6": {1e8: (14.12, 14.12), 2.5e8: (12.3, 12.3),
                                   5e8: (11.52, 11.52), 7.5e8: (9.31, 9.31), 1e9: (9.58, 9.58)},
}
BASELINES = ("uniform", "bayes")
READINGS = ("expected", "poisson")
HELDOUT = EnvSpec(rows=9, cols=13, area_m=(900.0, 1300.0), agents=6,
                  intensity=IntensitySpec.fixed(3e8), moves=4, walls=(1, 3))
"""Generalist's held-out configuration: grid, team size, intensity and walls outside training."""


def _policy(path: Path, spec: EnvSpec):
    """A model directory's policy rebuilt for ``spec`` (rejects what its actor cannot take)."""
    from workers.mdrl.commands.evaluate import model_policy_for
    from workers.mdrl.modelio import load_model

    policy = load_model(path)
    return model_policy_for(path, spec, policy.env_spec, policy)


def _training(path: Path) -> dict:
    card = json.loads((path / "model.json").read_text())
    training = card.get("training", {})
    return {"steps": training.get("env_steps"), "minutes": (training.get("wall_time_s") or 0) / 60}


def _row(name: str, r: EvalReport | None, oracle: EvalReport,
         thesis: tuple[float, float] | None = None, training: dict | None = None) -> dict:
    if r is not None:
        c, s = compare(r, oracle), r.summary
        return {"policy": name, "success": s["success_rate"], "time": s["time_mean"],
                "time_ci": s["time_ci"], "cost": s["cost_mean"], "cost_ci": s["cost_ci"],
                "time_ratio": c.time_ratio, "cost_ratio": c.cost_ratio, "paired": True,
                "training": training}
    t, cost = thesis
    return {"policy": name, "success": None, "time": t, "time_ci": None, "cost": cost,
            "cost_ci": None, "time_ratio": t / oracle.time_mean,
            "cost_ratio": cost / oracle.cost_mean, "paired": False, "training": None}


def _block(title: str, spec: EnvSpec, models: list[Path], episodes: int, seed: int,
           thesis: dict[str, tuple[float, float]]) -> dict:
    start = time.perf_counter()
    oracle = evaluate(make_baseline("oracle"), spec, episodes, seed=seed)
    rows = [_row("oracle (lower bound)", oracle, oracle)]
    for name in BASELINES:
        rows.append(_row(name, evaluate(make_baseline(name), spec, episodes, seed=seed), oracle))
    for path in models:
        report = evaluate(_policy(path, spec), spec, episodes, seed=seed, name=str(path))
        rows.append(_row(path.name, report, oracle, training=_training(path)))
    rows += [_row(f"{name} (thesis)", None, oracle, tc) for name, tc in thesis.items()]
    return {"title": title, "readings": spec.readings, "env": spec.to_dict(), "rows": rows,
            "seconds": time.perf_counter() - start}


def _fmt(row: dict) -> str:
    def num(v, ci):
        half = f" ±{(ci[1] - ci[0]) / 2:4.2f}" if ci and ci[0] == ci[0] else "      "
        return f"{v:6.2f}{half}"

    mark = "" if row["paired"] else "~"
    success = "     -" if row["success"] is None else f"{100 * row['success']:5.1f}%"
    tr = row["training"]
    trained = f"  {tr['steps'] / 1e6:5.2f}M steps {tr['minutes']:5.1f} min" if tr else ""
    return (f"  {row['policy']:<24} {success}  {num(row['time'], row['time_ci'])}  "
            f"{num(row['cost'], row['cost_ci'])}  {mark + format(row['time_ratio'], '.2f'):>6}  "
            f"{mark + format(row['cost_ratio'], '.2f'):>6}{trained}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--models", type=Path, default=Path("models"), help="zoo directory")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--teams", default="1,2,3,4,10")
    parser.add_argument("--intensities", default="1e8,2.5e8,5e8,7.5e8,1e9")
    parser.add_argument("--readings", default="expected,poisson")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead")
    args = parser.parse_args(argv)
    try:
        teams = [int(v) for v in args.teams.split(",") if v]
        intensities = [float(v) for v in args.intensities.split(",") if v]
    except ValueError:
        parser.error("--teams / --intensities: expected comma-separated numbers")
    readings = [r for r in args.readings.split(",") if r]
    if any(r not in READINGS for r in readings):
        parser.error(f"--readings: choose from {READINGS}")
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")

    def zoo(n: int) -> list[Path]:
        return [args.models / f"{k}-{n}a" for k in ("odmtl", "dmtl", "cmtl")
                if (args.models / f"{k}-{n}a" / "model.json").is_file()]

    blocks = []
    for rd in readings:
        for n in teams:
            spec = EnvSpec(agents=n, readings=rd)
            blocks.append(_block(f"Table 3.5, {n} agent(s), I = 1e9", spec, zoo(n),
                                 args.episodes, args.seed, TABLE_3_5.get(n, {})))
        for intensity in intensities:
            spec = EnvSpec(agents=3, intensity=IntensitySpec.fixed(intensity), readings=rd)
            thesis = {k: v[intensity] for k, v in TABLE_3_6.items() if intensity in v}
            blocks.append(_block(f"Table 3.6, 3 agents, I = {intensity:g}", spec, zoo(3),
                                 args.episodes, args.seed, thesis))
        generalist = args.models / "odmtl-generalist"
        if (generalist / "model.json").is_file():
            blocks.append(_block("generalist, held-out: 9x13, 6 agents, I = 3e8, walls 1-3",
                                 HELDOUT.replace(readings=rd), [generalist], args.episodes,
                                 args.seed, {}))

    if args.json:
        print(json.dumps({"episodes": args.episodes, "seed": args.seed, "blocks": blocks}))
        return 0
    print(f"{args.episodes} episodes per row, seed {args.seed}; ± = half-width of the 95% CI "
          "(Student t); ratios to the oracle on the same episodes (~ = thesis figure over our "
          "oracle's mean); 'expected' = noise-free readings (thesis comparison), 'poisson' = "
          "product default")
    for block in blocks:
        print(f"\n{block['title']}, {block['readings']} readings  ({block['seconds']:.1f} s)")
        print(f"  {'policy':<24} {'success':>6}  {'time':>12}  {'cost':>12}"
              f"  {'t/orc':>6}  {'c/orc':>6}")
        for row in block["rows"]:
            print(_fmt(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())
