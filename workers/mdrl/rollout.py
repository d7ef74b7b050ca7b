"""Rollout storage and action selection for CLDE (DMTL/ODMTL) and the joint actor (CMTL).

CLDE (centralized learning, decentralized execution, Alg. 3.3): every agent runs the shared
actor on its own observation, so a batch of B envs gives B * N actor samples per step.
CMTL: one joint actor picks one index over A**N joint actions (agent 0 is the most
significant digit), decoded into the N per-agent actions.

Buffers are preallocated and time first, `[T, B, Np, ...]` with Np = N (CLDE) or 1 (CMTL).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch

from workers.mdrl.observations import decode_joint, joint_mask
from workers.mdrl.ppo import masked_log_probs


class PolicyHead:
    """Maps env masks to policy masks and policy actions back to env actions (CLDE or CMTL)."""

    def __init__(self, num_actions: int, agents: int, joint: bool):
        self.num_actions = num_actions
        self.agents = agents
        self.joint = joint
        self.policy_agents = 1 if joint else agents
        """Np: actor samples per env step."""
        self.policy_actions = num_actions ** agents if joint else num_actions
        """Ap: size of the actor's output."""

    def policy_mask(self, env_mask: np.ndarray) -> np.ndarray:
        """(B, N, A) valid actions -> (B, Np, Ap); a joint action is valid if all its parts are."""
        if not self.joint:
            return env_mask
        return joint_mask(env_mask)[:, None, :]

    def env_actions(self, policy_actions: np.ndarray) -> np.ndarray:
        """(B, Np) policy actions -> (B, N) per-agent env actions."""
        if not self.joint:
            return policy_actions
        return decode_joint(policy_actions[:, 0], self.num_actions, self.agents)


class ActionSelector(Protocol):
    """Chooses policy actions from masked log-probabilities (B, Np, Ap).

    Hook for demonstration cloning (Alg. 4.1): an expert-guided selector can look at `env`,
    ask an expert for action scores (B, N, A) and pick the best-scored action whose
    probability under the policy exceeds l; the default samples from the policy.
    `episode_start(env_ids)` is called for envs that just began an episode (the trainer calls
    it for all envs before the first step), so a selector can draw per-episode decisions.
    A selector with state adds `state_dict() -> JSON-able` and `load_state_dict(d)`; the
    trainer then checkpoints it.
    """

    def episode_start(self, env_ids: np.ndarray) -> None: ...

    def select(self, logp: torch.Tensor, mask: torch.Tensor, env: Any) -> torch.Tensor: ...


def step_weights(selector: Any, envs: int) -> np.ndarray | None:
    """Policy-loss weight (B,) of each env's step just selected, if the selector gives one
    (``sample_weights(envs)``, e.g. MEDC's expert probation), else None = all 1."""
    fn = getattr(selector, "sample_weights", None)
    return None if fn is None else fn(envs)


class SampleSelector:
    """Samples from the policy (Gumbel-max with an explicit torch.Generator: reproducible)."""

    def __init__(self, generator: torch.Generator):
        self.generator = generator

    def episode_start(self, env_ids: np.ndarray) -> None:
        pass

    def select(self, logp: torch.Tensor, mask: torch.Tensor, env: Any) -> torch.Tensor:
        u = torch.rand(logp.shape, generator=self.generator).clamp_(1e-12, 1.0 - 1e-7)
        gumbel = -torch.log(-torch.log(u))
        return (logp + gumbel).masked_fill(~mask, float("-inf")).argmax(-1)


class GreedySelector:
    """Most probable valid action (evaluation, Alg. 3.4)."""

    def episode_start(self, env_ids: np.ndarray) -> None:
        pass

    def select(self, logp: torch.Tensor, mask: torch.Tensor, env: Any) -> torch.Tensor:
        return logp.masked_fill(~mask, float("-inf")).argmax(-1)


def policy_step(agent: Any, actor_obs: torch.Tensor, mask: torch.Tensor,
                selector: ActionSelector, env: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """Run the shared actor on (B, Np, C, H, W) observations; returns actions and log-probs (B, Np).

    The agent sees a flat batch of B * Np samples: one shared actor for all agents (CLDE).
    """
    b, n = actor_obs.shape[:2]
    logits = agent.logits(actor_obs.reshape(b * n, *actor_obs.shape[2:]), mask.reshape(b * n, -1))
    logp_all = masked_log_probs(logits, mask.reshape(b * n, -1)).reshape(b, n, -1)
    actions = selector.select(logp_all, mask, env)
    logp = logp_all.gather(-1, actions.unsqueeze(-1)).squeeze(-1)
    return actions, logp


@dataclass
class RolloutBuffer:
    """Preallocated, time-first storage for one PPO update (T steps of B envs)."""

    actor_obs: torch.Tensor  # float32 [T, B, Np, C_a, H, W]
    critic_obs: torch.Tensor  # float32 [T, B, C_c, H, W]
    masks: torch.Tensor  # bool [T, B, Np, Ap]
    actions: torch.Tensor  # int64 [T, B, Np]
    logp: torch.Tensor  # float32 [T, B, Np]
    values: torch.Tensor  # float32 [T, B]  (centralized critic, one value per env step)
    rewards: torch.Tensor  # float32 [T, B]  (team reward, Eq. 5)
    dones: torch.Tensor  # bool [T, B]  (episode ended with this step: terminated or truncated)
    weights: torch.Tensor  # float32 [T, B]  (policy-loss weight of the step; 1 unless a
    #                        selector gives one, ``step_weights``)

    @classmethod
    def allocate(cls, steps: int, envs: int, policy_agents: int, policy_actions: int,
                 actor_shape: tuple[int, ...], critic_shape: tuple[int, ...]) -> RolloutBuffer:
        t, b, n = steps, envs, policy_agents
        return cls(
            actor_obs=torch.zeros((t, b, n, *actor_shape), dtype=torch.float32),
            critic_obs=torch.zeros((t, b, *critic_shape), dtype=torch.float32),
            masks=torch.zeros((t, b, n, policy_actions), dtype=torch.bool),
            actions=torch.zeros((t, b, n), dtype=torch.int64),
            logp=torch.zeros((t, b, n), dtype=torch.float32),
            values=torch.zeros((t, b), dtype=torch.float32),
            rewards=torch.zeros((t, b), dtype=torch.float32),
            dones=torch.zeros((t, b), dtype=torch.bool),
            weights=torch.ones((t, b), dtype=torch.float32),
        )

    @property
    def steps(self) -> int:
        return self.rewards.shape[0]
