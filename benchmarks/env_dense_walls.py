"""Env steps/s near the walls bound: the rejection draws and recursive redraws vs the fast paths.

A spec with many walls for its grid (10x10 with 25 walls on its 32 wall slots) or whose layouts
fit the team just above ``env.MIN_FIT_RATE`` spent its time resetting: ``draw_walls`` redrew
every wall whose slot was taken (coupon collecting), and ``_reset_rows`` split a batch with a
layout too small for the team in two and recursed, drawing every layout again. Specs above
``env.DENSE_WALLS_SHARE`` now draw the slots directly and specs under
``env.REDRAW_LOOP_FIT_RATE`` redraw the misfits in a loop (the same laws, another stream;
``docs/mdrl-core.md``). Each spec is stepped both ways: "old" sets those two constants so
that the old paths run (the code they ran before, kept for ordinary specs), "new" as shipped.

The timed region is ``env.step`` alone (random valid actions drawn outside it; no observer),
autoresets included. Figures are env-steps/s (B envs stepped once = B env-steps), the best
of ``--repeats`` by wall clock and by this process's CPU time (the machine is shared: CPU time
does not count waiting for a core). A benchmark line, not an assertion.

Usage:
  python benchmarks/env_dense_walls.py                      # the specs below, B = 64
  python benchmarks/env_dense_walls.py --batch 1024 --seconds 3
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from workers.mdrl import env as env_module  # noqa: E402
from workers.mdrl.env import TargetLocalizationEnv  # noqa: E402
from workers.mdrl.presets import get_preset  # noqa: E402
from workers.mdrl.spec import EnvSpec  # noqa: E402

SPECS: dict[str, EnvSpec] = {
    "10x10, 3 agents, 25 walls (fit 21%)": EnvSpec(rows=10, cols=10, agents=3, walls=(25, 25)),
    "10x10, 3 agents, 18 walls (fit 56%)": EnvSpec(rows=10, cols=10, agents=3, walls=(18, 18)),
    "10x10, 3 agents, 10 walls (fit 86%)": EnvSpec(rows=10, cols=10, agents=3, walls=(10, 10)),
    "8x16, 3 agents, 8 moves, 30 walls (fit 20%)": EnvSpec(rows=8, cols=16, agents=3, moves=8,
                                                           walls=(30, 30)),
    "preset ch4-a3w3-sr-10x10 (unchanged)": get_preset("ch4-a3w3-sr-10x10").env,
}


def rate(spec: EnvSpec, B: int, seconds: float) -> tuple[float, float, float]:
    """(wall-clock env-steps/s, CPU env-steps/s, CPU seconds of the first full reset)."""
    c0 = time.process_time()
    env = TargetLocalizationEnv(spec, B, seed=0)
    reset_cpu = time.process_time() - c0
    rng = np.random.default_rng(0)
    steps, timed, cpu = 0, 0.0, 0.0
    while timed < seconds:
        mask = env.action_mask()
        actions = (rng.random(mask.shape) * mask).argmax(-1)
        t0, c0 = time.perf_counter(), time.process_time()
        env.step(actions)
        timed += time.perf_counter() - t0
        cpu += time.process_time() - c0
        steps += 1
    return steps * B / timed, steps * B / max(cpu, 1e-9), reset_cpu


def measure(spec: EnvSpec, B: int, seconds: float, repeats: int, old: bool
            ) -> tuple[float, float, float]:
    saved = env_module.DENSE_WALLS_SHARE, env_module.REDRAW_LOOP_FIT_RATE
    if old:
        env_module.DENSE_WALLS_SHARE, env_module.REDRAW_LOOP_FIT_RATE = float("inf"), 0.0
    try:
        runs = [rate(spec, B, seconds) for _ in range(repeats)]
    finally:
        env_module.DENSE_WALLS_SHARE, env_module.REDRAW_LOOP_FIT_RATE = saved
    return max(r[0] for r in runs), max(r[1] for r in runs), min(r[2] for r in runs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=64, help="B, envs stepped together")
    ap.add_argument("--seconds", type=float, default=2.0, help="timed seconds per run")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    TargetLocalizationEnv(SPECS[next(iter(SPECS))], 1, seed=0)  # load the compiled kernels
    print(f"# env steps/s near the walls bound, B = {args.batch}, step only (autoresets "
          f"included), best of {args.repeats}; wall clock (CPU time); first reset CPU time")
    for name, spec in SPECS.items():
        fit = env_module._FIT_RATES.get(spec)
        if fit is None:
            TargetLocalizationEnv(spec, 1, seed=0)
            fit = env_module._FIT_RATES[spec]
        slots = TargetLocalizationEnv.wall_slots(spec)
        print(f"{name}: walls {spec.walls[1]}/{slots} slots, fit rate {fit:.1%}")
        for old in (True, False):
            wall, cpu, reset = measure(spec, args.batch, args.seconds, args.repeats, old)
            what = "old: rejection + recursion" if old else "new: as shipped"
            print(f"  {what:<28} {wall:>12,.0f} env-steps/s ({cpu:>12,.0f} CPU)"
                  f"   reset of {args.batch}: {reset * 1e3:,.1f} ms")


if __name__ == "__main__":
    main()
