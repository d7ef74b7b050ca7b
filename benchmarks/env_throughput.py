"""Environment throughput in agent-steps/s, observations included (target >= 1e6 at B=1024).

Batched ``TargetLocalizationEnv`` + ODMTL observer at B = 1, 64, 1024 against stepping the
PettingZoo view one environment at a time. Random valid actions are drawn outside the timed
region; the timed region is ``env.step`` + ``observer.observe``. Single-threaded numpy.
Usage: python benchmarks/env_throughput.py [--agents 3] [--grid 10x10] [--kind odmtl] [--seconds 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.observations import ObservationSpec, make_observer
from workers.mdrl.parallel_env import TargetLocalizationParallelEnv
from workers.mdrl.spec import EnvSpec, parse_grid


def batched(spec: EnvSpec, obs_spec: ObservationSpec, B: int, seconds: float) -> float:
    env = TargetLocalizationEnv(spec, B, seed=0)
    observer = make_observer(spec, obs_spec)
    rng = np.random.default_rng(0)
    observer.observe(env)
    steps, timed = 0, 0.0
    while timed < seconds:
        keys = rng.random(env.action_mask().shape) * env.action_mask()
        actions = keys.argmax(-1)
        t0 = time.perf_counter()
        env.step(actions)
        observer.observe(env)
        timed += time.perf_counter() - t0
        steps += 1
    return steps * B * spec.agents / timed


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--agents", type=int, default=3)
    ap.add_argument("--grid", default="10x10")
    ap.add_argument("--kind", default="odmtl", choices=["odmtl", "dmtl", "cmtl"])
    ap.add_argument("--window", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=3.0)
    args = ap.parse_args()
    rows, cols = parse_grid(args.grid)
    spec = EnvSpec(rows=rows, cols=cols, agents=args.agents)
    obs_spec = ObservationSpec(args.kind, window=args.window)
    what = f"{args.kind.upper()} w={args.window}, {args.agents} agents, {args.grid}"
    print(f"# env throughput: {what}, step + observe")
    ref = pettingzoo(spec, obs_spec, args.seconds)
    print(f"{'PettingZoo view, 1 env at a time':<36} {ref:>14,.0f} agent-steps/s   1.0x")
    for B in (1, 64, 1024):
        rate = batched(spec, obs_spec, B, args.seconds)
        print(f"{f'batched B={B}':<36} {rate:>14,.0f} agent-steps/s {rate / ref:>6.1f}x")
    print("target: >= 1,000,000 agent-steps/s at B=1024")


if __name__ == "__main__":
    main()
