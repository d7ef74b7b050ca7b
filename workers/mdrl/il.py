"""IL-assisted RL (MDRL-IL), the thesis' benchmark for DC / MEDC (Sec. 4.7.3, 5.4.2 [17]).

The learner alternates an RL stage (PPO on its own experience, 80% of the updates) with an
imitation stage (20%): in an imitation update the team acts as the experts say (one expert per
episode, roulette wheel over R_S = QoS / sum QoS as in MEDC, every agent taking the expert's
best-ranked valid action whatever its own policy thinks of it) and the actor is then fitted
to those actions by behaviour cloning (cross-entropy), "blindly copying" them without
weighing the reward they earned. The critic keeps regressing on the returns of every rollout,
so it does not go stale during imitation.

This is what MEDC (medc.py) is compared with: the same experts, the same env-step budget; the
difference is that MEDC keeps PPO's own advantage-weighted update on guided experience and
follows an expert only where its own policy finds the action probable (threshold l), so bad
advice is unlearned through the reward, while BC writes it into the actor.

A checkpoint adds the imitation selector's state (roulette RNG, per-env expert) and the stage
counter to the trainer's, so ``ImitationTrainer.resume`` continues as the run would have. The
experts are models loaded by reference, not stored: the checkpoint records their identities
(reference, QoS weight, weight digest of a model) and resuming with other experts is refused.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from workers.mdrl.medc import DemonstrationSelector
from workers.mdrl.ppo import gae, masked_log_probs
from workers.mdrl.train import Trainer

IL_SHARE = 0.2
"""Share of the updates that are imitation stages ("the RL stage ... is 80% of the learning",
Sec. 4.7.3)."""


class ImitationTrainer(Trainer):
    """PPO (``Trainer``) with every ``round(1 / il_share)``-th update a behaviour-cloning stage
    on a rollout the experts drove (module docstring)."""

    def __init__(self, *args: Any, experts: Sequence[Any], qos: Sequence[float] | None = None,
                 il_share: float = IL_SHARE, **kwargs: Any):
        super().__init__(*args, **kwargs)
        if not experts:
            raise ValueError("ImitationTrainer needs at least one expert")
        if not (0 < il_share <= 1 and math.isfinite(il_share)):
            raise ValueError(f"il_share must lie in (0, 1], got {il_share!r}")
        self.il_share = il_share
        # rate 1: every episode follows an expert; threshold below 0: every valid action the
        # expert ranks best is taken, however improbable under the learner (blind imitation)
        self.imitator = DemonstrationSelector(experts, qos, rate=1.0, seed=self.run.seed)
        self.imitator.threshold = -1.0
        self.imitator.bind(self.generator)
        self.imitator.episode_start(torch.arange(self.ppo.num_envs).numpy())
        self.imitation_updates = 0
        self.expert_ids = [expert_identity(e, q)
                           for e, q in zip(experts, self.imitator.config.weights, strict=True)]

    @property
    def period(self) -> int:
        """Updates per RL + imitation cycle."""
        return max(1, round(1 / self.il_share))

    def imitating(self) -> bool:
        """Whether the coming update is an imitation stage (the last of every period)."""
        return self.update_idx % self.period == self.period - 1

    def collect(self) -> dict[str, float]:
        if not self.imitating():
            return super().collect()
        own, self.selector = self.selector, self.imitator
        try:
            return super().collect()
        finally:
            self.selector = own
            # the episodes the experts started go on under the learner's own policy
            self.selector.episode_start(torch.arange(self.ppo.num_envs).numpy())

    def update(self) -> dict[str, float]:
        if not self.imitating():
            return super().update()
        self.imitation_updates += 1
        return self.clone_update()

    def clone_update(self) -> dict[str, float]:
        """Behaviour cloning on the rollout just collected: maximise the log-probability of the
        experts' actions (cross-entropy), plus the critic's regression on the Monte-Carlo-GAE
        returns of the same rollout."""
        cfg, buf, agent = self.ppo, self.buffer, self.agent
        t, k = self._rollout
        _, returns = gae(buf.rewards[:t], buf.values[:t], buf.dones[:t], self.last_value,
                         cfg.gamma, cfg.gae_lambda)
        b, n = buf.actions.shape[1:]
        m = (t - 1) * b + k
        b_actor = buf.actor_obs[:t].reshape(t * b, n, *buf.actor_obs.shape[3:])[:m]
        b_critic = buf.critic_obs[:t].reshape(t * b, *buf.critic_obs.shape[2:])[:m]
        b_mask = buf.masks[:t].reshape(t * b, n, -1)[:m]
        b_actions = buf.actions[:t].reshape(t * b, n)[:m]
        b_ret = returns.reshape(t * b)[:m]
        mb_size = math.ceil(m / cfg.num_minibatches)
        bc_sum, v_sum, acc_sum, count = 0.0, 0.0, 0.0, 0
        for _epoch in range(cfg.update_epochs):
            perm = torch.randperm(m, generator=self.generator)
            for start in range(0, m, mb_size):
                idx = perm[start:start + mb_size]
                j = idx.numel()
                mask = b_mask[idx].reshape(j * n, -1)
                logp_all = masked_log_probs(
                    agent.logits(b_actor[idx].reshape(j * n, *b_actor.shape[2:]), mask), mask)
                target = b_actions[idx].reshape(j * n)
                bc_loss = -logp_all.gather(-1, target.unsqueeze(-1)).mean()
                v_loss = 0.5 * (agent.value(b_critic[idx]).reshape(j) - b_ret[idx]).pow(2).mean()
                loss = bc_loss + cfg.vf_coef * v_loss
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(agent.actor.parameters(), cfg.max_grad_norm)
                torch.nn.utils.clip_grad_norm_(agent.critic.parameters(), cfg.max_grad_norm)
                self.optimizer.step()
                bc_sum += bc_loss.item()
                v_sum += v_loss.item()
                acc_sum += (logp_all.argmax(-1) == target).float().mean().item()
                count += 1
        nan = math.nan
        return {"learning_rate": self.optimizer.param_groups[0]["lr"],
                "loss": (bc_sum + cfg.vf_coef * v_sum) / count, "policy_loss": bc_sum / count,
                "value_loss": v_sum / count, "entropy": nan, "approx_kl": nan,
                "clipfrac": nan, "explained_variance": nan,
                "imitation_accuracy": acc_sum / count}

    # ------------------------------------------------------------------ checkpoints
    def config_dict(self) -> dict[str, Any]:
        return {**super().config_dict(),
                "imitation": {"il_share": self.il_share, "experts": self.expert_ids}}

    def checkpoint_extras(self) -> dict[str, Any]:
        """The stage's state: imitation updates so far and the imitator's roulette."""
        return {"imitation_state": {"updates": self.imitation_updates,
                                    "imitator": self.imitator.state_dict()}}

    def load_state(self, tensors: dict[str, torch.Tensor], env_arrays: dict[str, Any],
                   meta: dict[str, Any]) -> None:
        saved, state = meta.get("imitation"), meta.get("imitation_state")
        if not saved or not state:
            raise ValueError("checkpoint holds no imitation state (not written by an "
                             "ImitationTrainer); resume it with Trainer.resume")
        diff = _expert_diff(saved["experts"], self.expert_ids)
        if diff:
            raise ValueError("cannot resume the IL run with other experts: " + "; ".join(diff))
        super().load_state(tensors, env_arrays, meta)
        self.imitator.load_state_dict(state["imitator"])
        self.imitation_updates = int(state["updates"])
        self.il_share = saved["il_share"]  # the run's schedule, whatever we were built with

    def save_model(self, path: Any, best: bool = False) -> Any:
        out = super().save_model(path, best=best)
        _add_training_note(out, {"method": "IL-assisted RL (behaviour cloning stages)",
                                 "il_share": self.il_share,
                                 "imitation_updates": self.imitation_updates,
                                 "experts": self.imitator.card()["experts"]})
        return out


def expert_identity(expert: Any, qos: float) -> dict[str, Any]:
    """What an IL checkpoint records of an expert it does not store: its reference (path, CID
    or built-in), QoS weight and, for a model, a digest of its weights (a path may be
    overwritten by another model)."""
    out: dict[str, Any] = {"ref": expert.name, "qos": float(qos)}
    agent = getattr(getattr(expert, "good", expert), "agent", None)  # malicious: its good one
    if agent is not None:
        from workers.mdrl.cae import tensor_digest

        out["digest"] = tensor_digest(agent.state_dict())
    return out


def _expert_diff(saved: list[dict[str, Any]], given: list[dict[str, Any]]) -> list[str]:
    """Human-readable differences between two lists of ``expert_identity``."""
    if len(saved) != len(given):
        return [f"the checkpoint has {len(saved)} expert(s) {[e['ref'] for e in saved]}, "
                f"given {len(given)} {[e['ref'] for e in given]}"]
    return [f"expert {i} {key}: {a.get(key)!r} in the checkpoint, {b.get(key)!r} given"
            for i, (a, b) in enumerate(zip(saved, given, strict=True))
            for key in sorted(a.keys() | b.keys()) if a.get(key) != b.get(key)]


def _add_training_note(model_dir: Any, note: dict[str, Any]) -> None:
    """Record how a benchmark model was trained in its card's ``training.method`` section."""
    from workers.mdrl.modelio import CARD

    card_path = Path(model_dir) / CARD
    card = json.loads(card_path.read_text())
    card.setdefault("training", {})["method"] = note
    card_path.write_text(json.dumps(card, indent=1))
