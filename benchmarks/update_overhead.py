"""The fixed cost of a PPO update that FLOPs do not see (``resources.update_overhead_seconds``).

Times updates of a 4 x 4 grid of one ODMTL agent with one env (their FLOPs are ~0.01 ms, so
what is measured is the per-update, per-rollout-step and per-optimizer-step overhead), each as
a worker's job runs it: ``collect``, ``update``, the metrics.csv row and the progress point.
Prints the median per update and the FLOP model's figure, then one update with a checkpoint.
One torch thread, one BLAS thread.

Usage:
  .venv/bin/python benchmarks/update_overhead.py       # ~1 min
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import json
import statistics
import tempfile
import time
from pathlib import Path

import torch

from workers.daemon.job import JobTrainer, progress_point
from workers.mdrl import resources
from workers.mdrl.trainingspec import TrainingSpec

CASES = [  # (horizon, update_epochs, num_minibatches, updates timed)
    (1, 1, 1, 400), (16, 1, 1, 200), (64, 1, 1, 60), (16, 4, 16, 60),
]


def spec(horizon: int, epochs: int, minibatches: int) -> TrainingSpec:
    return TrainingSpec.from_dict({
        "env": {"rows": 4, "cols": 4, "agents": 1},
        "observation": {"kind": "odmtl", "window": 3},
        "algorithm": {"ppo": {"num_envs": 1, "horizon": horizon, "update_epochs": epochs,
                              "num_minibatches": minibatches}},
        "budget": {"steps": 10**9},
    })


def per_update(s: TrainingSpec, updates: int, checkpoint: bool = False) -> float:
    """Median seconds of one update (after 5 warm-up updates)."""
    out = Path(tempfile.mkdtemp())
    run = s.run_config(tensorboard=False, progress=False, threads=1)
    trainer = JobTrainer(s.env, s.observation, s.ppo, run, out=out)
    trainer._open_outputs()
    points = out / "progress.jsonl"

    def on_row(row: dict) -> None:
        with points.open("a") as f:
            f.write(json.dumps(progress_point(row)) + "\n")

    trainer.on_row = on_row
    times = []
    for _ in range(updates + 5):
        t0 = time.perf_counter()
        episodes, losses = trainer.collect(), trainer.update()
        trainer.update_idx += 1
        trainer._log({"update": trainer.update_idx, "global_step": trainer.global_step,
                      "wall_time": 0.0, "sps": 1.0, **losses, **episodes})
        if checkpoint:
            trainer.save_checkpoint(out / "checkpoint")
        times.append(time.perf_counter() - t0)
    return statistics.median(times[5:])


def main() -> None:
    torch.set_num_threads(1)
    rate = resources.reference_flops_per_s()
    for horizon, epochs, minibatches, n in CASES:
        s = spec(horizon, epochs, minibatches)
        flops_s = resources.flops_per_step(s) * s.ppo.batch_steps / rate
        print(f"horizon {horizon:3}, {epochs} epoch(s), {minibatches:2} minibatch(es): "
              f"{per_update(s, n) * 1e3:7.1f} ms per update (FLOPs {flops_s * 1e3:.3f} ms, "
              f"model {resources.update_seconds(s) * 1e3:.1f} ms)", flush=True)
    s = spec(1, 1, 1)
    print(f"horizon   1 with a checkpoint every update: {per_update(s, 200, True) * 1e3:7.1f} "
          "ms per update")


if __name__ == "__main__":
    main()
