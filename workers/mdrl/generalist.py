"""One ODMTL actor for many set-ups: PPO over a mix of grid sizes, team sizes, intensities and
walls (issue 9's generalist).

Why it can work: ODMTL's inputs are w x w windows and w x w downsized maps whatever the grid
(thesis 3.6.1), the others map is kept for a lone agent (``ObservationSpec(others=True)``) and
the wall maps are always on, so one actor (and one reduced critic) takes every set-up. The belief
map carries the physics of each set-up, so the policy only has to learn to search a posterior.

How: ``SETUPS`` set-ups are drawn once from a seeded generator (rows and cols in 8-16 with 100 m
cells, 1-5 agents, intensity uniform in [1e8, 1e9], 0-2 walls); each gets a ``Trainer`` with
its own envs, observer and rollout buffer, and all of them share one ``ActorCritic`` and one
Adam optimizer. Each PPO update uses one set-up, in turn. Checkpoints keep the shared weights,
the optimizer and the counters; a resumed run draws fresh episodes (the env states of a dozen
set-ups are not worth keeping for this one model).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from workers.mdrl import checkpoint as ckpt
from workers.mdrl.networks import ActorCritic
from workers.mdrl.observations import ObservationSpec
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.spec import EnvSpec, IntensitySpec
from workers.mdrl.train import RunConfig, Trainer

SETUPS = 12
GRID = (8, 16)
AGENTS = (1, 5)
INTENSITY = IntensitySpec.uniform(1e8, 1e9)
WALLS = (0, 2)
CELL_M = 100.0
OBSERVATION = ObservationSpec(kind="odmtl", window=5, walls=True, readings="mean",
                              scale="fixed", belief=True, others=True)


def training_setups(seed: int, count: int = SETUPS) -> list[EnvSpec]:
    """The set-ups the generalist trains on (seeded; grid, team, walls and intensity vary)."""
    rng = np.random.default_rng(seed)
    specs = []
    for _ in range(count):
        rows, cols = (int(v) for v in rng.integers(GRID[0], GRID[1] + 1, size=2))
        agents = int(rng.integers(AGENTS[0], AGENTS[1] + 1))
        specs.append(EnvSpec(rows=rows, cols=cols, area_m=(rows * CELL_M, cols * CELL_M),
                             agents=agents, intensity=INTENSITY, walls=WALLS))
    return specs


def card_spec() -> EnvSpec:
    """The env the model file names (a middle set-up); `drlaas eval` flags change it."""
    return EnvSpec(rows=12, cols=12, area_m=(12 * CELL_M, 12 * CELL_M), agents=3,
                   intensity=INTENSITY, walls=WALLS)


class GeneralistTrainer:
    """PPO over several set-ups with one shared actor-critic (module docstring)."""

    def __init__(self, ppo: PPOConfig, run: RunConfig, out: str | Path,
                 setups: list[EnvSpec] | None = None) -> None:
        if run.keep_best is not None:
            raise ValueError("the generalist keeps its final policy only (it evaluates per "
                             "set-up, not on one episode set): drop RunConfig.keep_best")
        self.ppo, self.run, self.out = ppo, run, Path(out)
        self.setups = setups if setups is not None else training_setups(run.seed)
        sub_run = dataclasses.replace(run, tensorboard=False, progress=False, total_steps=None,
                                      minutes=None)
        self.trainers = [Trainer(spec, OBSERVATION, ppo, dataclasses.replace(
            sub_run, seed=run.seed + 1000 * (k + 1))) for k, spec in enumerate(self.setups)]
        shapes = {(t.observer.actor_shape, t.observer.critic_shape) for t in self.trainers}
        if len(shapes) != 1:
            raise ValueError(f"set-ups disagree on the network inputs: {sorted(shapes)}")
        with torch.random.fork_rng():
            torch.manual_seed(run.seed)
            self.agent = ActorCritic(self.trainers[0].observer,
                                     self.trainers[0].head.policy_actions)
        self.optimizer = torch.optim.Adam(self.agent.parameters(), lr=ppo.learning_rate,
                                          eps=ppo.adam_eps)
        for t in self.trainers:
            t.agent, t.optimizer = self.agent, self.optimizer
        self.update_idx = self.global_step = 0
        self.elapsed = 0.0

    def budget_left(self) -> bool:
        return self.run.budget_left(self.global_step, self.elapsed)

    def train(self) -> dict[str, Any]:
        """Updates in turn over the set-ups until the budget is used; writes metrics.csv."""
        torch.set_num_threads(self.run.threads)
        self.out.mkdir(parents=True, exist_ok=True)
        log = self.out / "metrics.csv"
        if self.update_idx == 0:
            log.write_text("update,global_step,wall_time,setup,success,episode_length,"
                           "episode_cost,entropy,explained_variance\n")
        t0, elapsed0 = time.perf_counter(), self.elapsed
        row: dict[str, Any] = {}
        while self.budget_left():
            k = self.update_idx % len(self.trainers)
            t = self.trainers[k]
            before = t.global_step
            stats = t.collect()
            losses = t.update()
            self.global_step += t.global_step - before
            self.update_idx += 1
            self.elapsed = elapsed0 + time.perf_counter() - t0
            row = {**stats, **losses}
            with log.open("a") as f:
                f.write(f"{self.update_idx},{self.global_step},{self.elapsed:.1f},{k},"
                        f"{_num(stats['success'])},{_num(stats['episode_length'])},"
                        f"{_num(stats['episode_cost'])},{losses['entropy']:.4f},"
                        f"{_num(losses['explained_variance'])}\n")
            if self.update_idx % (2 * len(self.trainers)) == 0 or not self.budget_left():
                self.save_checkpoint()
        self.save_model(self.out / "model")
        return row

    # ------------------------------------------------------------------ files
    def save_checkpoint(self) -> None:
        path = self.out / "checkpoint"
        path.mkdir(parents=True, exist_ok=True)
        tensors = {f"agent/{k}": v.contiguous() for k, v in self.agent.state_dict().items()}
        opt_tensors, opt_meta = ckpt.optimizer_to_parts(self.optimizer)
        tensors.update(opt_tensors)
        save_file(tensors, str(path / "generalist.safetensors"))
        meta = {"update": self.update_idx, "global_step": self.global_step,
                "elapsed": self.elapsed, "optimizer": opt_meta, "ppo": self.ppo.to_dict(),
                "run": self.run.to_dict(), "setups": [s.to_dict() for s in self.setups]}
        (path / "generalist.json").write_text(json.dumps(meta))

    @classmethod
    def resume(cls, out: str | Path, run_overrides: dict[str, Any] | None = None
               ) -> GeneralistTrainer:
        path = Path(out) / "checkpoint"
        meta = json.loads((path / "generalist.json").read_text())
        run = RunConfig.from_dict({**meta["run"], **(run_overrides or {})})
        setups = [EnvSpec.from_dict(d) for d in meta["setups"]]
        trainer = cls(PPOConfig.from_dict(meta["ppo"]), run, out, setups=setups)
        tensors = load_file(str(path / "generalist.safetensors"))
        trainer.agent.load_state_dict(
            {k[len("agent/"):]: v for k, v in tensors.items() if k.startswith("agent/")})
        ckpt.optimizer_from_parts(trainer.optimizer, tensors, meta["optimizer"])
        trainer.update_idx, trainer.global_step = meta["update"], meta["global_step"]
        trainer.elapsed = meta["elapsed"]
        return trainer

    def save_model(self, path: str | Path) -> Path:
        from workers.mdrl.modelio import save_model

        spec = card_spec()
        setups = [{"rows": s.rows, "cols": s.cols, "agents": s.agents} for s in self.setups]
        return save_model(path, self.agent, spec, OBSERVATION, self.ppo,
                          training={"run": self.run.to_dict(), "env_steps": self.global_step,
                                    "updates": self.update_idx, "wall_time_s": self.elapsed,
                                    "generalist": {"setups": setups, "cell_m": CELL_M,
                                                   "intensity": str(INTENSITY),
                                                   "walls": list(WALLS)}})


def _num(v: float) -> str:
    return "" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.4f}"
