"""Warm start: clone a search policy (e.g. the Bayesian searcher) before PPO takes over.

Why: PPO from scratch spends most of its budget discovering what a model-based searcher
already does (walk towards the posterior mass, let one agent go when one is enough). Cloning
that behaviour first and then optimising the team reward with PPO reaches the searcher's level
in minutes and leaves PPO to improve on it (docs/learning.md has the ablation).

Algorithm (DAgger, Ross et al. 2011, with a decaying expert share): for ``rounds`` rounds,
B envs are stepped for ``steps / rounds`` env steps; at each step the expert labels every
agent's observation with its action, and the team executes the expert's joint action with
probability ``beta_r = 1 - r / rounds`` (per env and step) or the student's greedy one
otherwise, so later rounds visit the states the student itself reaches. After each round the
actor is fitted by cross-entropy to every label so far (masked logits), and the critic by
least squares to the discounted team returns (reward scaled as in PPO) of the finished
episodes. The executed trajectories are not PPO samples: PPO starts afterwards with its own
rollouts, and the warm start's env steps are counted in the run's budget.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from workers.mdrl.baselines import make_baseline
from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.observations import encode_joint
from workers.mdrl.ppo import masked_log_probs

EXPERTS = ("bayes", "oracle", "uniform")


@dataclass(frozen=True)
class WarmStart:
    """How to clone a searcher before PPO (module docstring)."""

    expert: str = "bayes"
    """Baseline to clone: bayes (the default; it sees only what the agents see), uniform, or
    oracle (knows the target: a cheat, for ablations only)."""
    steps: int = 100_000
    """Env steps of the warm start (all rounds), counted in the run's step budget."""
    rounds: int = 4
    """DAgger rounds; the expert executes with probability 1 - r / rounds in round r."""
    epochs: int = 3
    """Passes over all labels so far after each round."""
    minibatch: int = 1024
    """Env steps per gradient step."""
    learning_rate: float = 1e-3

    def __post_init__(self) -> None:
        if self.expert not in EXPERTS:
            raise ValueError(f"WarmStart.expert must be one of {EXPERTS}, got {self.expert!r}")
        for name in ("steps", "rounds", "epochs", "minibatch"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"WarmStart.{name} must be >= 1, got {getattr(self, name)}")
        if not self.learning_rate > 0:
            raise ValueError(f"WarmStart.learning_rate must be > 0, got {self.learning_rate}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> WarmStart:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"WarmStart: unknown field(s) {unknown}; known: {sorted(names)}")
        return cls(**d)


def _returns(rewards: np.ndarray, dones: np.ndarray, gamma: float) -> tuple[np.ndarray, np.ndarray]:
    """(T, B) discounted returns within episodes and whether each step's episode finished
    inside the window (unfinished tails have no return to regress on)."""
    t_len, b = rewards.shape
    ret = np.zeros((t_len, b), np.float32)
    known = np.zeros((t_len, b), bool)
    acc = np.zeros(b, np.float32)
    finished = np.zeros(b, bool)
    for t in range(t_len - 1, -1, -1):
        finished = np.where(dones[t], True, finished)
        acc = np.where(dones[t], 0.0, acc) * gamma + rewards[t]
        acc = np.where(dones[t], rewards[t], acc)
        ret[t], known[t] = acc, finished
    return ret, known


def warm_start(trainer: Any, cfg: WarmStart) -> dict[str, float]:
    """Clone ``cfg.expert`` into ``trainer.agent`` (actor and critic); returns figures of the
    last round. Uses its own envs and RNG streams, so the PPO rollouts that follow are the
    same whatever the warm start did, except for the weights it leaves."""
    spec, ppo, run = trainer.env_spec, trainer.ppo, trainer.run
    observer, head, agent = trainer.observer, trainer.head, trainer.agent
    b = ppo.num_envs
    env = TargetLocalizationEnv(spec, b, seed=run.seed + 7_919)
    expert = make_baseline(cfg.expert, seed=run.seed)
    expert.reset(env)
    rng = np.random.default_rng(run.seed + 104_729)
    gen = torch.Generator().manual_seed(run.seed + 15_485_863)
    opt = torch.optim.Adam(agent.parameters(), lr=cfg.learning_rate, eps=1e-5)
    per_round = max(1, math.ceil(cfg.steps / cfg.rounds / b))
    data: dict[str, list[torch.Tensor]] = {"actor": [], "critic": [], "mask": [], "label": [],
                                           "ret": [], "known": []}
    stats: dict[str, float] = {}
    taken = 0
    for r in range(cfg.rounds):
        beta = 1.0 - r / cfg.rounds
        rewards = np.zeros((per_round, b), np.float32)
        dones = np.zeros((per_round, b), bool)
        for t in range(per_round):
            actor_obs, critic_obs = observer.observe(env)
            # copy: the env's mask is a view that the step below rewrites
            mask = torch.from_numpy(np.array(head.policy_mask(env.action_mask()), dtype=bool))
            label = expert.act(env)  # (B, N) env actions; called every step (stateful)
            lab = encode_joint(label, spec.num_actions)[:, None] if head.joint else label
            a_obs = torch.as_tensor(actor_obs)
            with torch.inference_mode():
                nb, n = a_obs.shape[:2]
                logits = agent.logits(a_obs.reshape(nb * n, *a_obs.shape[2:]),
                                      mask.reshape(nb * n, -1))
                own = head.env_actions(logits.argmax(-1).reshape(nb, n).numpy())
            follow = rng.random(b) < beta
            res = env.step(np.where(follow[:, None], label, own))
            data["actor"].append(a_obs.clone())
            data["critic"].append(torch.as_tensor(critic_obs).clone())
            data["mask"].append(mask.clone())
            data["label"].append(torch.as_tensor(np.asarray(lab, dtype=np.int64)))
            rewards[t] = res.reward * ppo.reward_scale
            dones[t] = res.terminated | res.truncated
        ret, known = _returns(rewards, dones, ppo.gamma)
        data["ret"].extend(torch.from_numpy(ret))
        data["known"].extend(torch.from_numpy(known))
        taken += per_round * b
        stats = _fit(agent, opt, data, cfg, gen)
        stats["warm_beta"] = beta
    stats["warm_steps"] = taken
    return stats


def _fit(agent: Any, opt: torch.optim.Optimizer, data: dict[str, list[torch.Tensor]],
         cfg: WarmStart, gen: torch.Generator) -> dict[str, float]:
    """Cross-entropy on the expert labels (actor) and MSE on known returns (critic)."""
    actor = torch.cat(data["actor"])  # (M, Np, C, H, W)
    critic = torch.cat(data["critic"])
    mask = torch.cat(data["mask"])
    label = torch.cat(data["label"])
    ret = torch.cat(data["ret"])
    known = torch.cat(data["known"])
    m, n = actor.shape[:2]
    ce_sum = acc_sum = v_sum = 0.0
    count = 0
    for _ in range(cfg.epochs):
        perm = torch.randperm(m, generator=gen)
        for start in range(0, m, cfg.minibatch):
            idx = perm[start:start + cfg.minibatch]
            k = idx.numel()
            mk = mask[idx].reshape(k * n, -1)
            logits = agent.logits(actor[idx].reshape(k * n, *actor.shape[2:]), mk)
            logp = masked_log_probs(logits, mk)
            lab = label[idx].reshape(k * n)
            ce = -logp.gather(-1, lab[:, None]).mean()
            kn = known[idx]
            value = agent.value(critic[idx]).reshape(k)
            v_loss = ((value - ret[idx]) ** 2 * kn).sum() / kn.sum().clamp(min=1)
            loss = ce + 0.5 * v_loss
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(agent.actor.parameters(), 0.5)
            torch.nn.utils.clip_grad_norm_(agent.critic.parameters(), 0.5)
            opt.step()
            ce_sum += float(ce.detach())
            v_sum += float(v_loss.detach())
            acc_sum += float((logp.argmax(-1) == lab).float().mean())
            count += 1
    return {"warm_cross_entropy": ce_sum / count, "warm_accuracy": acc_sum / count,
            "warm_value_loss": v_sum / count}
