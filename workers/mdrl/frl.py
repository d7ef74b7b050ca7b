"""Federated RL (FRL), the thesis' model-averaging benchmark for MEDC (Sec. 2.2.5, 5.4.2 [54, 55]).

Several users train the same architecture with PPO, each on its own environment (the thesis'
eight users A1W0, A3W0, A2W1, A2W2, A2W3, A3W1, A3W2, A3W3); after every ``local_updates``
updates their weights are averaged (FedAvg, equal weights: every user collects the same number
of env steps) and the global model goes back to every user, who carries on from it with its
own optimiser state. Results are read "from the perspective of" one target user (A3W2 or
A3W3): its env steps are the x-axis, its environment is where the global model is evaluated.

Averaging needs one architecture for all users, so every user sees the same input set: wall
maps even where there are no walls and the others map even for a lone agent
(``ObservationSpec(walls=True, others=True)``); all users must share the move set. This is
the constraint the thesis holds against FRL (Sec. 5.1): MEDC's experts need not share anything.

Faulty users (the thesis' Fig. 5.8: 3 of the 8 users share faulty models) train nothing and
send a poisoned copy of the global model to every average (``poisoned_model``): ``random``
draws every weight at random at the scale of the global model's tensor, ``biased`` makes the
actor always pick one action, ``malicious`` negates the actor's head so the global model's
ranking is reversed (its best action last), the weight-averaging analogues of the random,
biased and malicious experts of Sec. 5.4.1 (experts.py).

Checkpoints (every ``run.checkpoint_every`` rounds and at the end, under ``out/checkpoint``)
hold every user's ``Trainer`` checkpoint in ``users/NAME``, the global model in
``global.safetensors`` and the federation's counters in ``frl.json``, written to a temp dir
and renamed, so ``FederatedTrainer.resume`` continues exactly as the run would have.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save_file

from workers.mdrl import checkpoint as ckpt
from workers.mdrl.observations import ObservationSpec
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.spec import EnvSpec
from workers.mdrl.train import RunConfig, Trainer

FORMAT = "drlaas-frl-checkpoint/1"
THESIS_USERS = ("A1W0", "A3W0", "A2W1", "A2W2", "A2W3", "A3W1", "A3W2", "A3W3")
"""The eight FRL users of Sec. 5.4.2: A = agents, W = walls."""
FAULTY_KINDS = ("random", "biased", "malicious")
"""What a faulty FRL user shares (module docstring); ``biased:K`` names the action."""
HEAD = "actor.net.10"
"""The actor's output layer in ``ActorCritic`` (LeNet's last Linear)."""
BIASED_LOGIT = 10.0
"""The biased head's logit of its one action (the others 0): e^10 ~ 2.2e4 to 1 per action."""


def faulty_kind(kind: str) -> tuple[str, int | None]:
    """``random`` / ``biased[:K]`` / ``malicious`` -> (name, K or None); ValueError otherwise."""
    name, sep, arg = str(kind).partition(":")
    if name not in FAULTY_KINDS or (sep and name != "biased"):
        raise ValueError(f"unknown faulty FRL user kind {kind!r}; known: random, biased[:K], "
                         f"malicious")
    if not sep:
        return name, None
    if not arg.isdigit():
        raise ValueError(f"biased FRL user: the action must be an integer, got {arg!r}")
    return name, int(arg)


def _scale(model: dict[str, torch.Tensor], key: str) -> float:
    """The spread of a tensor's values; a constant one (fresh zero biases) takes its layer's
    weights' spread, so a random user's biases are random too."""
    for k in (key, key.rsplit(".", 1)[0] + ".weight"):
        v = model.get(k)
        if v is not None and v.numel() > 1:
            std = float(v.float().std())
            if math.isfinite(std) and std > 0:
                return std
    return 1.0


def poisoned_model(kind: str, global_model: dict[str, torch.Tensor],
                   generator: torch.Generator) -> dict[str, torch.Tensor]:
    """What a faulty user of kind ``random``, ``biased[:K]`` or ``malicious`` sends to FedAvg."""
    name, action = faulty_kind(kind)
    out = {k: v.clone() for k, v in global_model.items()}
    if name == "random":
        for k in sorted(out):  # one order whatever the dict's (a loaded checkpoint's is sorted)
            v = out[k]
            if v.is_floating_point():
                noise = torch.randn(v.shape, generator=generator)
                out[k] = (noise * _scale(global_model, k)).to(v.dtype)
        return out
    weight, bias = out[f"{HEAD}.weight"], out[f"{HEAD}.bias"]
    if name == "malicious":
        out[f"{HEAD}.weight"], out[f"{HEAD}.bias"] = -weight, -bias
        return out
    action = len(bias) - 1 if action is None else action
    if not 0 <= action < len(bias):
        raise ValueError(f"biased FRL user: action {action} is not one of 0..{len(bias) - 1}")
    out[f"{HEAD}.weight"] = torch.zeros_like(weight)
    out[f"{HEAD}.bias"] = torch.zeros_like(bias)
    out[f"{HEAD}.bias"][action] = BIASED_LOGIT
    return out


def federated_input(obs_spec: ObservationSpec) -> ObservationSpec:
    """The one input set every FRL user shares (module docstring)."""
    return dataclasses.replace(obs_spec, walls=True, others=True)


class FederatedTrainer:
    """FedAvg over per-user PPO trainers; ``train()`` runs until the target user's step or
    time budget (``run``) is used. ``out`` receives the target user's metrics.csv and model, and
    the checkpoint (module docstring)."""

    def __init__(self, users: Sequence[tuple[str, EnvSpec]], obs_spec: ObservationSpec,
                 ppo: PPOConfig, run: RunConfig, target: str, local_updates: int = 1,
                 out: str | Path | None = None, faulty: dict[str, str] | None = None):
        names = [name for name, _ in users]
        faulty = dict(faulty or {})
        if set(faulty) - set(names) or target in faulty:
            raise ValueError(f"faulty FRL users must be users other than the target "
                             f"{target!r}, got {sorted(faulty)} of {names}")
        for kind in faulty.values():
            faulty_kind(kind)
        if len(set(names)) != len(names):
            raise ValueError(f"FRL users must have distinct names, got {names}")
        bad = [n for n in names if not n or Path(n).name != n or n.startswith(".")]
        if bad:  # each user's checkpoint is a directory named after it
            raise ValueError(f"FRL user names must be plain file names, got {bad}")
        if target not in names:
            raise ValueError(f"FRL target user {target!r} is not one of {names}")
        if local_updates < 1:
            raise ValueError(f"local_updates must be >= 1, got {local_updates}")
        moves = {spec.moves for _, spec in users}
        if len(moves) != 1:
            raise ValueError(f"FRL averages one actor: all users need the same move set, got "
                             f"{sorted(moves)}")
        obs = federated_input(obs_spec)
        self.run, self.target, self.local_updates = run, target, local_updates
        self.out = Path(out) if out is not None else None
        self.users, self.faulty = list(users), faulty
        self.poison_rng = torch.Generator().manual_seed(run.seed * 7919 + 1)
        self.trainers: dict[str, Trainer] = {}
        for i, (name, spec) in enumerate(users):
            if name in faulty:  # trains nothing: it only sends poison (module docstring)
                continue
            user_run = dataclasses.replace(
                run, seed=run.seed * 1009 + i, eval_every=0, checkpoint_every=0,
                progress=False, tensorboard=False, total_steps=None, minutes=None)
            self.trainers[name] = Trainer(spec, obs, ppo, user_run,
                                          out=self.out if name == target else None)
        shapes = {name: tuple((k, tuple(v.shape)) for k, v in t.agent.state_dict().items())
                  for name, t in self.trainers.items()}
        if len(set(shapes.values())) != 1:
            raise ValueError("FRL users ended up with different network shapes; give every "
                             "user the same observation kind, window and move set")
        self.global_model = {k: v.clone() for k, v in self.trainer.agent.state_dict().items()}
        for kind in faulty.values():  # a biased action beyond the head fails now, not later
            poisoned_model(kind, self.global_model, torch.Generator())
        self._broadcast()
        self.rounds = 0
        self.elapsed = 0.0

    @property
    def trainer(self) -> Trainer:
        """The target user's trainer (its env steps and environment are what is reported)."""
        return self.trainers[self.target]

    @property
    def global_step(self) -> int:
        return self.trainer.global_step

    def _broadcast(self) -> None:
        for t in self.trainers.values():
            t.agent.load_state_dict(self.global_model)

    @torch.no_grad()
    def average(self) -> None:
        """FedAvg: the global model is the mean of the users' weights (the faulty users' poison
        included); every honest user gets it back."""
        states = [t.agent.state_dict() for t in self.trainers.values()]
        states += [poisoned_model(kind, self.global_model, self.poison_rng)
                   for kind in self.faulty.values()]
        self.global_model = {k: torch.stack([s[k].float() for s in states]).mean(0).to(v.dtype)
                             for k, v in states[0].items()}
        self._broadcast()
        self.rounds += 1

    def budget_left(self) -> bool:
        return self.run.budget_left(self.global_step, self.elapsed)

    def train(self) -> dict[str, Any]:
        """Local PPO updates on every user, FedAvg every ``local_updates`` updates, greedy
        evaluation of the global model on the target's env every ``run.eval_every`` rounds.
        The last round is cut short where the budget ends, so the target user's steps overshoot
        it by less than one update whatever ``local_updates`` is (as a lone ``Trainer``)."""
        if self.run.total_steps is None and self.run.minutes is None:
            raise ValueError("FederatedTrainer.train: give a budget (total_steps and/or minutes)")
        torch.set_num_threads(self.run.threads)
        target = self.trainer
        target._open_outputs()
        t0, elapsed0 = time.perf_counter(), self.elapsed

        def left() -> bool:
            return self.run.budget_left(self.global_step, elapsed0 + time.perf_counter() - t0)

        while self.budget_left():
            step0 = self.global_step
            u0 = time.perf_counter()
            for _ in range(self.local_updates):
                for name, t in self.trainers.items():
                    stats = t.collect()
                    losses = t.update()
                    t.update_idx += 1
                    if name == self.target:
                        episode_stats, loss_stats = stats, losses
                if not left():
                    break  # the budget ends this round early: average what was trained
            self.average()
            last = not left()
            every = self.run.eval_every
            evals: dict[str, float] = {}
            if last or (every and self.rounds % every == 0):
                evals = target.evaluate()
                target.last_eval = evals
                target.keep_if_best(evals)
            self.elapsed = elapsed0 + (time.perf_counter() - t0)
            sps = (self.global_step - step0) / max(time.perf_counter() - u0, 1e-9)
            row = {"update": target.update_idx, "global_step": self.global_step,
                   "wall_time": self.elapsed, "sps": sps, **loss_stats, **episode_stats, **evals}
            target._log(row)
            ce = self.run.checkpoint_every
            if self.out is not None and (last or (ce and self.rounds % ce == 0)):
                self.save_checkpoint(self.out / "checkpoint")
        target.elapsed = self.elapsed
        if self.out is not None:
            target.save_model(self.out / "model")
            from workers.mdrl.il import _add_training_note

            steps = sum(t.global_step for t in self.trainers.values())
            _add_training_note(self.out / "model", {
                "method": "FRL (FedAvg across users)", "users": [n for n, _ in self.users],
                "target": self.target, "local_updates": self.local_updates,
                "rounds": self.rounds, "env_steps_all_users": steps,
                **({"faulty_users": self.faulty} if self.faulty else {})})
        return target.last_metrics

    # ------------------------------------------------------------------ checkpoints
    def save_checkpoint(self, path: str | Path) -> Path:
        """Write every user's checkpoint, the global model and the counters to a temp dir,
        then swap it in for ``path`` (a crash leaves the previous checkpoint whole)."""
        with ckpt.atomic_dir(path) as tmp:
            for name, t in self.trainers.items():
                t.save_checkpoint(tmp / "users" / name)
            save_file({k: v.contiguous() for k, v in self.global_model.items()},
                      str(tmp / "global.safetensors"))
            target = self.trainer
            meta = {"format": FORMAT, "rounds": self.rounds, "elapsed": self.elapsed,
                    "target": self.target, "local_updates": self.local_updates,
                    "users": [[name, spec.to_dict()] for name, spec in self.users],
                    "faulty": self.faulty, "poison_rng": self.poison_rng.get_state().tolist(),
                    "observation": target.obs_spec.to_dict(), "ppo": target.ppo.to_dict(),
                    "run": self.run.to_dict()}
            (tmp / "frl.json").write_text(json.dumps(meta, indent=1))
        return Path(path)

    @classmethod
    def resume(cls, path: str | Path, out: str | Path | None = None,
               run_overrides: dict[str, Any] | None = None) -> FederatedTrainer:
        """Rebuild an FRL run from a checkpoint dir (or a run dir holding ``checkpoint/``)."""
        path = Path(path)
        if (path / "checkpoint").is_dir():
            path = path / "checkpoint"
        try:
            meta = json.loads((path / "frl.json").read_text())
            global_model = load_file(str(path / "global.safetensors"))
        except (OSError, ValueError, SafetensorError) as exc:
            raise ValueError(f"not a readable FRL checkpoint {path}: {exc}") from exc
        if meta.get("format") != FORMAT:
            raise ValueError(f"{path}: unknown FRL checkpoint format {meta.get('format')!r}")
        users = [(name, EnvSpec.from_dict(d)) for name, d in meta["users"]]  # seeds by order
        faulty = meta.get("faulty") or {}
        run = RunConfig.from_dict({**meta["run"], **(run_overrides or {})})
        frl = cls(users, ObservationSpec.from_dict(meta["observation"]),
                  PPOConfig.from_dict(meta["ppo"]), run, meta["target"], meta["local_updates"],
                  out=out if out is not None else path.parent, faulty=faulty)
        if "poison_rng" in meta:
            frl.poison_rng.set_state(torch.tensor(meta["poison_rng"], dtype=torch.uint8))
        # every user made ``local_updates`` updates a round, but the last one if the budget
        # cut it short (train)
        rounds, k = meta["rounds"], meta["local_updates"]
        for name, t in frl.trainers.items():
            user = path / "users" / name
            try:
                t.load_state(*ckpt.load_checkpoint(user))
            except (OSError, ValueError, KeyError, RuntimeError, SafetensorError) as exc:
                raise ValueError(f"FRL checkpoint {path}: user {name}'s checkpoint {user} "
                                 f"cannot be loaded: {exc}") from exc
        for name, t in frl.trainers.items():
            if t.update_idx != frl.trainer.update_idx or -(-t.update_idx // k) != rounds:
                raise ValueError(f"FRL checkpoint {path}: user {name} is at update "
                                 f"{t.update_idx}, the target user at update "
                                 f"{frl.trainer.update_idx}, the federation at round {rounds} "
                                 f"of {k} updates")
        frl.global_model = global_model
        frl.rounds, frl.elapsed = meta["rounds"], meta["elapsed"]
        return frl
