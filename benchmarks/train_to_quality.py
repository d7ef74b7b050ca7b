"""Train to thesis quality: wall-clock and env steps until greedy evaluation reaches Table 3.5.

Quality bar (issue 2): ODMTL w = 3, 3 agents, 10 x 10, I = 1e9; greedy success >= 99 % with
mean time <= 5.8 and mean cost <= 6.3 (thesis Table 3.5), evaluated on fixed seeded episodes
every ``--eval-every`` updates. Also short-budget runs of DMTL and CMTL for 1-4 agents, and the
oracle's figures on the very same evaluation episodes for scale.

Usage: python benchmarks/train_to_quality.py [--minutes 10] [--short-minutes 1] [--skip-short]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

from workers.mdrl.baselines import make_baseline
from workers.mdrl.evaluate import evaluate
from workers.mdrl.presets import get_preset
from workers.mdrl.train import RunConfig, Trainer

TABLE_3_5 = {  # (time, cost) lowest averages per team size, thesis Table 3.5
    "cmtl": {1: (9.8, 9.8), 2: (7.7, 13.1)},
    "dmtl": {1: (9.0, 9.0), 2: (5.5, 7.8), 3: (4.7, 5.1), 4: (4.5, 4.8)},
    "odmtl": {1: (8.3, 8.3), 2: (5.7, 8.1), 3: (5.8, 6.3), 4: (5.5, 5.8)},
}


def run(
    preset_name: str,
    minutes: float,
    eval_every: int,
    episodes: int,
    seed: int,
    stop_at: tuple[float, float, float] | None,
    threads: int,
    readings: str,
    out: str | None = None,
) -> dict:
    """Train update by update; evaluate greedily; stop at the quality bar or the time budget."""
    preset = get_preset(preset_name)
    preset = dataclasses.replace(preset, env=preset.env.replace(readings=readings))
    runcfg = RunConfig(
        seed=seed,
        minutes=minutes,
        eval_every=0,
        eval_episodes=episodes,
        threads=threads,
        tensorboard=False,
        progress=False,
    )
    trainer = Trainer(preset.env, preset.observation, preset.ppo, runcfg, out=None)
    t0 = time.perf_counter()
    best, reached, evals = None, None, 0
    while True:
        out_of_time = time.perf_counter() - t0 >= minutes * 60
        if out_of_time and best is not None:
            break
        if not out_of_time:
            trainer.collect()
            trainer.update()
            trainer.update_idx += 1
            if trainer.update_idx % eval_every:
                continue
        e = trainer.evaluate()
        evals += 1
        point = {
            "steps": trainer.global_step,
            "seconds": round(time.perf_counter() - t0, 1),
            "success": e["eval_success"],
            "time": e["eval_time"],
            "cost": e["eval_cost"],
        }
        if best is None or (point["success"], -point["time"] - point["cost"]) > (
            best["success"],
            -best["time"] - best["cost"],
        ):
            best = point
        if (
            stop_at
            and point["success"] >= stop_at[0]
            and point["time"] <= stop_at[1]
            and point["cost"] <= stop_at[2]
        ):
            reached = point
            break
    if out:
        trainer.save_model(out)
    oracle = evaluate(make_baseline("oracle"), preset.env, episodes, seed=runcfg.eval_seed)
    return {
        "preset": preset_name,
        "readings": readings,
        "budget_minutes": minutes,
        "evaluations": evals,
        "steps": trainer.global_step,
        "best": best,
        "reached": reached,
        "oracle_time": oracle.time_mean,
        "oracle_cost": oracle.cost_mean,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="budget of the ODMTL quality run")
    ap.add_argument("--short-minutes", type=float, default=1.0, help="budget of each short run")
    ap.add_argument("--skip-short", action="store_true")
    ap.add_argument("--eval-every", type=int, default=5)
    ap.add_argument("--episodes", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument(
        "--readings",
        default="poisson",
        choices=["poisson", "expected"],
        help="reading model: Poisson draws (issue) or expected counts (author's code)",
    )
    ap.add_argument("--out", default=None, help="save the ODMTL model here (for policy_table.py)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    results = []
    r = run(
        "odmtl-3a-10x10",
        args.minutes,
        args.eval_every,
        args.episodes,
        args.seed,
        (0.99, 5.8, 6.3),
        args.threads,
        args.readings,
        args.out,
    )
    results.append(r)
    if not args.skip_short:
        for kind, sizes in (("dmtl", (1, 2, 3, 4)), ("cmtl", (1, 2, 3))):
            for n in sizes:
                results.append(
                    run(
                        f"{kind}-{n}a-10x10",
                        args.short_minutes,
                        args.eval_every,
                        args.episodes,
                        args.seed,
                        None,
                        args.threads,
                        args.readings,
                    )
                )
    if args.json:
        print(json.dumps(results, indent=1))
        return
    q = results[0]
    print(
        f"# train to Table 3.5 quality: ODMTL w=3, 3 agents, 10x10, I=1e9, {args.readings} readings"
    )
    if q["reached"]:
        p = q["reached"]
        print(
            f"reached success {p['success']:.3f}, time {p['time']:.2f}, cost {p['cost']:.2f} "
            f"after {p['seconds']:.0f} s and {p['steps']:,} env steps"
        )
    else:
        b = q["best"]
        print(
            f"NOT reached in {q['budget_minutes']:g} min ({q['steps']:,} env steps); best: "
            f"success {b['success']:.3f}, time {b['time']:.2f}, cost {b['cost']:.2f} "
            f"at {b['seconds']:.0f} s / {b['steps']:,} steps"
        )
    print(
        f"{'preset':<16} {'min':>5} {'steps':>11} {'success':>8} {'time':>6} {'cost':>6} "
        f"{'thesis t/c':>11} {'oracle t':>9} {'time/oracle':>12}"
    )
    for r in results:
        b = r["reached"] or r["best"]
        kind, n = r["preset"].split("-")[0], int(r["preset"].split("-")[1][:-1])
        thesis = TABLE_3_5.get(kind, {}).get(n)
        th = f"{thesis[0]:.1f}/{thesis[1]:.1f}" if thesis else "n/a"
        print(
            f"{r['preset']:<16} {r['budget_minutes']:>5g} {r['steps']:>11,} {b['success']:>8.3f} "
            f"{b['time']:>6.2f} {b['cost']:>6.2f} {th:>11} {r['oracle_time']:>9.2f} "
            f"{b['time'] / r['oracle_time']:>12.2f}"
        )


if __name__ == "__main__":
    main()
