"""Trained policies vs thesis Tables 3.5/3.6 and the uniform, Bayesian and oracle baselines.

3 agents, 10x10 over 1 km x 1 km, 4 moves, no walls (thesis Sec. 3.7.1), one fixed intensity per
block (the five of Table 3.6). Every policy of a block runs the very same seeded episodes
(``workers.mdrl.evaluate``), so the ratios to the oracle (time = cost = min BFS distance, the
lower bound) are paired. Thesis rows are the published means: their episodes are other random
draws of the same set-up, so their ratios (marked ~) use our oracle's mean as the reference.
Table 3.6's DDQN is a single agent; Table 3.5 (3 agents, I = 1e9) gives the lowest means
reached during training, Table 3.6 the ODMTL means at the end.

Usage: python benchmarks/policy_table.py [MODEL_DIR ...] [--episodes 1000] [--seed 0]
       [--intensities 1e8,2.5e8,5e8,7.5e8,1e9] [--json]
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

#: Table 3.6: (time, cost) per target strength; DDQN is one agent, so time = cost.
TABLE_3_6 = {
    "ODMTL (thesis T3.6)": {
        1e8: (11.27, 13.3),
        2.5e8: (9.27, 10.99),
        5e8: (8.61, 9.76),
        7.5e8: (7.71, 9.38),
        1e9: (7.54, 8.78),
    },
    "DDQN 1 agent (thesis T3.6)": {
        1e8: (14.12, 14.12),
        2.5e8: (12.3, 12.3),
        5e8: (11.52, 11.52),
        7.5e8: (9.31, 9.31),
        1e9: (9.58, 9.58),
    },
}
#: Table 3.5, 3 agents (I = 1e9): lowest mean time and cost reached.
TABLE_3_5 = {"DMTL (thesis T3.5)": (4.7, 5.1), "ODMTL (thesis T3.5)": (5.8, 6.3)}
BASELINES = ("uniform", "bayes")


def _load(path: str, spec: EnvSpec):
    """A model directory's policy rebuilt for ``spec`` (rejects what its actor cannot take)."""
    from workers.mdrl.commands.evaluate import model_policy_for
    from workers.mdrl.modelio import load_model

    policy = load_model(path)
    return model_policy_for(Path(path), spec, policy.env_spec, policy)


def _row(
    name: str, r: EvalReport | None, oracle: EvalReport, thesis: tuple[float, float] | None = None
) -> dict:
    if r is not None:
        c = compare(r, oracle)
        s = r.summary
        return {
            "policy": name,
            "success": s["success_rate"],
            "time": s["time_mean"],
            "time_ci": s["time_ci"],
            "cost": s["cost_mean"],
            "cost_ci": s["cost_ci"],
            "time_ratio": c.time_ratio,
            "cost_ratio": c.cost_ratio,
            "paired": True,
        }
    t, cost = thesis
    return {
        "policy": name,
        "success": 1.0,
        "time": t,
        "time_ci": None,
        "cost": cost,
        "cost_ci": None,
        "time_ratio": t / oracle.time_mean,
        "cost_ratio": cost / oracle.cost_mean,
        "paired": False,
    }


def _fmt(row: dict) -> str:
    def num(v, ci):
        return f"{v:6.2f}" + (
            f" ±{(ci[1] - ci[0]) / 2:4.2f}" if ci and ci[0] == ci[0] else "      "
        )

    mark = "" if row["paired"] else "~"
    return (
        f"  {row['policy']:<30} {100 * row['success']:6.1f}%  {num(row['time'], row['time_ci'])}  "
        f"{num(row['cost'], row['cost_ci'])}  {mark + format(row['time_ratio'], '.2f'):>6}  "
        f"{mark + format(row['cost_ratio'], '.2f'):>6}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("models", nargs="*", help="model directories (3 agents, 10x10)")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--intensities", default="1e8,2.5e8,5e8,7.5e8,1e9")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead")
    args = parser.parse_args(argv)
    try:
        intensities = [float(v) for v in args.intensities.split(",")]
    except ValueError:
        parser.error(f"--intensities: expected comma-separated numbers, got {args.intensities!r}")
    if args.episodes < 1:
        parser.error("--episodes must be >= 1")

    blocks = []
    for intensity in intensities:
        spec = EnvSpec(agents=3, intensity=IntensitySpec.fixed(intensity))
        start = time.perf_counter()
        oracle = evaluate(make_baseline("oracle"), spec, args.episodes, seed=args.seed)
        rows = [_row("oracle (lower bound)", oracle, oracle)]
        for name in BASELINES:
            rows.append(
                _row(
                    name, evaluate(make_baseline(name), spec, args.episodes, seed=args.seed), oracle
                )
            )
        for path in args.models:
            report = evaluate(_load(path, spec), spec, args.episodes, seed=args.seed, name=path)
            rows.append(_row(path, report, oracle))
        for name, values in TABLE_3_6.items():
            if intensity in values:
                rows.append(_row(name, None, oracle, values[intensity]))
        if intensity == 1e9:
            rows += [_row(name, None, oracle, tc) for name, tc in TABLE_3_5.items()]
        blocks.append(
            {"intensity": intensity, "rows": rows, "seconds": time.perf_counter() - start}
        )

    if args.json:
        print(
            json.dumps(
                {
                    "episodes": args.episodes,
                    "seed": args.seed,
                    "agents": 3,
                    "grid": "10x10",
                    "blocks": blocks,
                }
            )
        )
        return 0
    print(
        f"3 agents, 10x10, 4 moves, no walls; {args.episodes} episodes per row, seed {args.seed}; "
        "± = half-width of the 95% CI (Student t); ratios to the oracle on the same episodes "
        "(~ = thesis figure over our oracle's mean)"
    )
    for block in blocks:
        print(f"\nI = {block['intensity']:g} photons/min  ({block['seconds']:.1f} s)")
        print(
            f"  {'policy':<30} {'success':>7}  {'time':>12}  {'cost':>12}"
            f"  {'t/orc':>6}  {'c/orc':>6}"
        )
        for row in block["rows"]:
            print(_fmt(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())
