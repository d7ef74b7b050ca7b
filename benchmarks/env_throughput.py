"""Environment throughput in agent-steps/s, observations included (target >= 1e6 at B=1024).

Batched ``TargetLocalizationEnv`` + observer at B = 1, 64, 1024 against stepping the
PettingZoo view one environment at a time. Random valid actions are drawn outside the timed
region; the timed region is ``env.step`` + ``observer.observe``. Each figure is measured
``--repeats`` times (``--seconds`` each): the best and the median are printed, since the
machine is shared; so is the best rate per second of this process's CPU time, which a busy
machine inflates much less than wall-clock time (it does not count time spent waiting for a
core).

numpy runs single-threaded (OPENBLAS/OMP/MKL_NUM_THREADS default to 1 here, set before numpy
loads): the env's products are small, and a multi-threaded OpenBLAS on a busy 2-core machine
made ``observe`` up to 20x slower (threads spinning against other processes).

Usage:
  python benchmarks/env_throughput.py                               # Ch. 3: 10x10, 4 moves, w=3
  python benchmarks/env_throughput.py --grid 30 --moves 8 --window 7   # Ch. 4 size, no walls
  python benchmarks/env_throughput.py --grid 30 --moves 8 --window 7 --walls 3
  python benchmarks/env_throughput.py --preset ch4-a3w3-sr          # a preset's env + observer
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from workers.mdrl.env import TargetLocalizationEnv  # noqa: E402
from workers.mdrl.observations import ObservationSpec, make_observer  # noqa: E402
from workers.mdrl.parallel_env import TargetLocalizationParallelEnv  # noqa: E402
from workers.mdrl.presets import get_preset  # noqa: E402
from workers.mdrl.spec import EnvSpec, parse_grid, parse_walls  # noqa: E402


def batched(spec: EnvSpec, obs_spec: ObservationSpec, B: int, seconds: float
            ) -> tuple[float, float]:
    """(wall-clock, CPU-time) agent-steps/s of step + observe."""
    env = TargetLocalizationEnv(spec, B, seed=0)
    observer = make_observer(spec, obs_spec)
    rng = np.random.default_rng(0)
    observer.observe(env)
    steps, timed, cpu = 0, 0.0, 0.0
    while timed < seconds:
        keys = rng.random(env.action_mask().shape) * env.action_mask()
        actions = keys.argmax(-1)
        t0, c0 = time.perf_counter(), time.process_time()
        env.step(actions)
        observer.observe(env)
        timed += time.perf_counter() - t0
        cpu += time.process_time() - c0
        steps += 1
    return steps * B * spec.agents / timed, steps * B * spec.agents / max(cpu, 1e-9)


def pettingzoo(spec: EnvSpec, obs_spec: ObservationSpec, seconds: float) -> float:
    env = TargetLocalizationParallelEnv(spec, obs_spec)
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=0)
    agent_steps, timed = 0, 0.0
    while timed < seconds:
        if not env.agents:
            t0 = time.perf_counter()
            obs, _ = env.reset()
            timed += time.perf_counter() - t0
        acts = {a: int(rng.choice(np.flatnonzero(obs[a]["action_mask"]))) for a in env.agents}
        t0 = time.perf_counter()
        obs, *_ = env.step(acts)
        timed += time.perf_counter() - t0
        agent_steps += len(acts)
    return agent_steps / timed


def setup(args: argparse.Namespace) -> tuple[EnvSpec, ObservationSpec, str]:
    if args.preset:
        p = get_preset(args.preset)
        return p.env, p.observation, f"preset {p.name}"
    rows, cols = parse_grid(args.grid if "x" in args.grid else f"{args.grid}x{args.grid}")
    spec = EnvSpec(rows=rows, cols=cols, agents=args.agents, moves=args.moves,
                   walls=parse_walls(args.walls))  # area: the default (speed does not use it)
    obs_spec = ObservationSpec(args.kind, window=args.window)
    what = (f"{args.kind.upper()} w={args.window}, {args.agents} agents, {rows}x{cols}, "
            f"{args.moves} moves, walls {args.walls}")
    return spec, obs_spec, what


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--agents", type=int, default=3)
    ap.add_argument("--grid", default="10x10", help="ROWSxCOLS or one side (30 = 30x30)")
    ap.add_argument("--moves", type=int, default=4, choices=[4, 8])
    ap.add_argument("--walls", default="0", help="a count (3) or a range (0-3)")
    ap.add_argument("--kind", default="odmtl", choices=["odmtl", "dmtl", "cmtl"])
    ap.add_argument("--window", type=int, default=3)
    ap.add_argument("--preset", default=None, help="take env and observation from a preset")
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--batches", default="1,64,1024")
    ap.add_argument("--no-pettingzoo", action="store_true", help="skip the 1-env reference")
    args = ap.parse_args()
    spec, obs_spec, what = setup(args)
    print(f"# env throughput: {what}, step + observe, best / median of {args.repeats}")
    ref = None
    if not args.no_pettingzoo:
        ref = pettingzoo(spec, obs_spec, args.seconds)
        print(f"{'PettingZoo view, 1 env at a time':<36} {ref:>14,.0f} agent-steps/s")
    for B in (int(b) for b in args.batches.split(",")):
        runs = [batched(spec, obs_spec, B, args.seconds) for _ in range(args.repeats)]
        rates = [wall for wall, _ in runs]
        best, median = max(rates), statistics.median(rates)
        ratio = f" {best / ref:>6.1f}x" if ref else ""
        print(f"{f'batched B={B}':<36} {best:>14,.0f} best {median:>14,.0f} median"
              f" agent-steps/s{ratio}   (CPU time: {max(c for _, c in runs):,.0f} best)")
    print("target: >= 1,000,000 agent-steps/s at B=1024")


if __name__ == "__main__":
    main()
