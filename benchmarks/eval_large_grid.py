"""Wall-clock of ``evaluate`` on a large grid, where the B x C x C cap of ``default_batch``
leaves one episode per seeded chunk (64 x 64: 1 episode per chunk).

Before the geometry cache (docs/mdrl-core.md, "Evaluation on large grids"), each chunk built a
``TargetLocalizationEnv`` whose constructor recomputed the C x C tables (~1 GB of temporaries
at 64 x 64), and stepped its one episode alone. Now the tables are built once per geometry and
a policy that allows it steps up to ``STEP_ENVS`` chunks together; the figures are the same.
Prints the first env construction (builds the geometry), a second one (cached) and the
evaluation of ``--episodes`` episodes of the oracle and, with ``--model``, of a trained model.

Usage:
  python benchmarks/eval_large_grid.py                      # oracle, 64 x 64, 100 episodes
  python benchmarks/eval_large_grid.py --model runs/g64/model --episodes 100
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import time  # noqa: E402

from workers.mdrl.baselines import OraclePolicy  # noqa: E402
from workers.mdrl.env import TargetLocalizationEnv  # noqa: E402
from workers.mdrl.evaluate import default_batch, evaluate  # noqa: E402
from workers.mdrl.spec import EnvSpec  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grid", type=int, default=64)
    ap.add_argument("--agents", type=int, default=2)
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--model", default=None, help="a model directory (its env at --grid)")
    args = ap.parse_args()
    policies = [("oracle", OraclePolicy())]
    spec = EnvSpec(rows=args.grid, cols=args.grid, agents=args.agents)
    if args.model:
        from workers.mdrl.modelio import load_model

        model = load_model(args.model)
        spec = model.env_spec.replace(rows=args.grid, cols=args.grid)
        policies.append((args.model, model))
    for label in ("first env", "second env"):
        t0 = time.perf_counter()
        TargetLocalizationEnv(spec, 1, seed=0, autoreset=False)
        print(f"{label} ({args.grid}x{args.grid}): {time.perf_counter() - t0:.2f} s")
    print(f"default_batch: {default_batch(spec, args.episodes)} episodes per chunk")
    for label, policy in policies:
        t0 = time.perf_counter()
        rep = evaluate(policy, spec, args.episodes, seed=0)
        print(f"evaluate {label}, {args.episodes} episodes: {time.perf_counter() - t0:.1f} s "
              f"(time {rep.time_mean:.2f}, cost {rep.cost_mean:.2f})")
    print(f"peak RSS: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
