"""PPO training of the MDRL models (Alg. 3.3): CLDE for DMTL/ODMTL, a joint actor for CMTL.

Reads top to bottom like CleanRL's ppo.py: config -> env -> observer -> agent -> rollout ->
GAE -> update -> log. CLDE: each agent's (observation, action, log-prob) is one sample for
the shared actor; the team reward (Eq. 5) and the centralized critic's value belong to the
env step and are shared by that env's agents (one advantage per env step, used by all N
agent samples). CMTL: one sample per env step over the A**N joint actions.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import logging
import math
import numbers
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from workers.mdrl import checkpoint as ckpt
from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.evaluate import MAX_EPISODES, evaluate
from workers.mdrl.networks import ActorCritic
from workers.mdrl.observations import ObservationSpec, make_observer
from workers.mdrl.ppo import PPOConfig, entropy_from_log_probs, gae, masked_log_probs, ppo_losses
from workers.mdrl.rollout import (
    ActionSelector,
    PolicyHead,
    RolloutBuffer,
    SampleSelector,
    policy_step,
    step_weights,
)
from workers.mdrl.spec import EnvSpec

log = logging.getLogger(__name__)

_monotonic = time.monotonic
"""The clock of the checkpoint interval (``Trainer.checkpoint_interval_s``)."""


@dataclass
class RunConfig:
    """How long and how a training run goes (not learning hyperparameters)."""

    seed: int = 0
    """Seeds the env layouts/noise, network init, action sampling and minibatch order."""
    total_steps: int | None = None
    """Env-step budget, met exactly (the last rollout is shortened); also the horizon of the
    learning-rate anneal."""
    minutes: float | None = None
    """Wall-clock budget in minutes (checked between updates, resumed runs count prior time)."""
    eval_every: int = 10
    """Greedy evaluation every this many updates (and after the last one); 0 = only at the end."""
    eval_episodes: int = 200
    """Fixed, seeded evaluation episodes (the same ones every time)."""
    eval_seed: int = 1_000_003
    """Seed of the evaluation episodes (independent of the training seed)."""
    checkpoint_every: int = 10
    """Save a checkpoint every this many updates (always after the last one); 0 = only at end."""
    threads: int = 1
    """torch intra-op threads (fixed so that runs are reproducible)."""
    tensorboard: bool = True
    """Write TensorBoard event files under out/tb."""
    progress: bool = True
    """Show a tqdm progress bar."""
    init_from: str | None = None
    """A model directory whose weights a new run starts from (fine-tuning; same observation,
    team size and actions, ``modelio.load_initial_weights``); None = random init from the seed.
    A resumed run continues from its checkpoint, not from this model."""
    keep_best: str | None = None
    """Also keep the best greedy evaluation's policy (``out/best``, ``Trainer.policy(best=True)``):
    ``"time"`` = shortest mean episode, ``"cost"`` = lowest mean moving cost (failed episodes
    count at the cap; ties go to the other figure, then to the earlier update). None = the
    final policy only. Model selection on the evaluation episodes (``eval_seed``): judge the
    chosen model on other episodes."""

    def __post_init__(self) -> None:
        if self.keep_best is not None and self.keep_best not in tuple(KEEP_BEST):  # [] too
            raise RunConfigError("keep_best", f"RunConfig.keep_best must be 'time', 'cost' or "
                                 f"None, got {self.keep_best!r}")
        ints = {"seed": (0, MAX_SEED), "eval_seed": (0, MAX_SEED), "eval_every": (0, None),
                "eval_episodes": (1, MAX_EPISODES), "checkpoint_every": (0, None),
                "threads": (1, None)}
        if self.total_steps is not None:
            ints["total_steps"] = (1, None)
        for name, (lo, hi) in ints.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Integral):
                raise RunConfigError(name, f"RunConfig.{name} must be an integer, got {v!r}")
            if v < lo or (hi is not None and v > hi):
                bound = f">= {lo}" if hi is None else f"in [{lo}, {hi}]"
                raise RunConfigError(name, f"RunConfig.{name} must be {bound}, got {v!r}")
        for name in ("tensorboard", "progress"):  # "no" or 1e30 read as true
            if not isinstance(getattr(self, name), bool):
                raise RunConfigError(name, f"RunConfig.{name} must be true or false, got "
                                     f"{getattr(self, name)!r}")
        m = self.minutes
        if m is not None and (isinstance(m, bool) or not isinstance(m, numbers.Real)
                              or not math.isfinite(m) or m <= 0):
            raise RunConfigError("minutes", f"RunConfig.minutes must be a finite number > 0 "
                                 f"(or None), got {m!r}")
        if self.init_from is not None and (not isinstance(self.init_from, str)
                                           or not self.init_from):
            raise RunConfigError("init_from", f"RunConfig.init_from must be a model directory "
                                 f"(or None), got {self.init_from!r}")

    def budget_left(self, global_step: int, elapsed_s: float) -> bool:
        """Whether a run that took ``global_step`` env steps in ``elapsed_s`` may go on."""
        if self.total_steps is not None and global_step >= self.total_steps:
            return False
        return not (self.minutes is not None and elapsed_s >= self.minutes * 60.0)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RunConfig:
        if not isinstance(d, dict):
            raise RunConfigError("", f"RunConfig: expected a table/object, got {d!r}")
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise RunConfigError(unknown[0], f"RunConfig: unknown field(s) {unknown}; known: "
                                 f"{sorted(names)}")
        return cls(**d)


class RunConfigError(ValueError):
    """A RunConfig value that is wrong; ``field`` names it (so a CLI can name its flag)."""

    def __init__(self, field: str, msg: str) -> None:
        super().__init__(msg)
        self.field = field


class TrainingDiverged(FloatingPointError):
    """The PPO loss or the network's weights became NaN or infinite: training stops before a
    broken policy is stepped, checkpointed or saved as a model."""


MAX_SEED = 2**63 - 1
"""Largest RunConfig seed / eval_seed (torch generators take 64-bit seeds; the trainer seeds
one with ``seed + 1``)."""

KEEP_BEST = {"time": ("eval_time", "eval_cost"), "cost": ("eval_cost", "eval_time")}
"""RunConfig.keep_best: the evaluation figures a better policy is lower in, in order."""

METRIC_COLUMNS = [
    "update", "global_step", "wall_time", "sps", "learning_rate",
    "loss", "policy_loss", "value_loss", "entropy", "approx_kl", "clipfrac", "explained_variance",
    "episodes", "success", "episode_length", "episode_cost", "episode_return",
    "eval_success", "eval_time", "eval_cost",
]
"""Columns of metrics.csv, one row per update; eval_* are empty between evaluations."""
TIMING_COLUMNS = ("wall_time", "sps")
"""Columns that depend on the machine; every other column is reproducible from the seed."""


def greedy_eval(policy: Any, spec: EnvSpec, episodes: int, seed: int) -> dict[str, float]:
    """Fixed, seeded episodes with `policy` via `evaluate.evaluate` (same episodes every call).

    Success = target found within max_steps; time = episode length (failures count as
    max_steps); cost = moving actions in the episode (both averaged over all episodes).
    """
    report = evaluate(policy, spec, episodes, seed=seed)
    return {"eval_success": report.success_rate, "eval_time": report.time_mean,
            "eval_cost": report.cost_mean}


class Trainer:
    """One PPO training run; `train()` runs it, `save_checkpoint` / `resume` continue it."""

    def __init__(self, env_spec: EnvSpec, obs_spec: ObservationSpec, ppo: PPOConfig,
                 run: RunConfig, out: str | Path | None = None,
                 selector: ActionSelector | None = None, walls_encoder: Any = None,
                 _resuming: bool = False):
        """``walls_encoder``: a ``cae.WallsEmbedder`` to use instead of loading
        ``obs_spec.walls_embedding`` from disk (a platform job fetches the CAE by CID and keeps
        the CID in the spec, so the model's card names it, not the worker's path).
        ``_resuming``: ``resume`` builds the trainer; its checkpoint, not ``run.init_from``,
        holds the weights."""
        self.env_spec, self.obs_spec, self.ppo, self.run = env_spec, obs_spec, ppo, run
        self.out = Path(out) if out is not None else None
        torch.set_num_threads(run.threads)
        # environment: B envs stepped together as arrays
        built = time.perf_counter()
        self.env = TargetLocalizationEnv(env_spec, ppo.num_envs, seed=run.seed)
        # observer: env state -> actor (B, Np, C, H, W) and critic (B, C, H, W) maps
        self.observer = make_observer(env_spec, obs_spec, walls_encoder)
        self._setup_s = time.perf_counter() - built
        """Seconds to build the env and observer (an evaluation builds its own)."""
        self._eval_s: float | None = None
        """Seconds the last greedy evaluation of this process took (None: none yet)."""
        self.head = PolicyHead(env_spec.num_actions, env_spec.agents,
                               joint=bool(self.observer.joint_actions))
        # agent: shared actor + centralized critic (Table 3.1); init from the seed only
        with torch.random.fork_rng():
            torch.manual_seed(run.seed)
            self.agent = ActorCritic(self.observer, self.head.policy_actions)
        self.init_info: dict[str, Any] | None = None
        if run.init_from and not _resuming:
            from workers.mdrl.modelio import load_initial_weights

            self.init_info = load_initial_weights(
                self.agent, run.init_from, obs_spec, self.observer, env_spec.agents,
                env_spec.num_actions)
        self.optimizer = torch.optim.Adam(self.agent.parameters(), lr=ppo.learning_rate,
                                          eps=ppo.adam_eps)
        self.generator = torch.Generator().manual_seed(run.seed + 1)
        self.selector = selector if selector is not None else SampleSelector(self.generator)
        if getattr(self.selector, "needs_step_budget", False) and run.total_steps is None:
            raise ValueError("experts rate_end (an expert rate schedule) needs a step budget: "
                             "give total_steps (--steps)")  # refused before anything is built
        if hasattr(self.selector, "bind"):  # an expert selector samples with our generator
            self.selector.bind(self.generator)
        self.selector.episode_start(np.arange(ppo.num_envs))
        # rollout storage, time first
        self.buffer = RolloutBuffer.allocate(
            ppo.rollout_steps, ppo.num_envs, self.head.policy_agents, self.head.policy_actions,
            tuple(self.observer.actor_shape), tuple(self.observer.critic_shape))
        # counters (checkpointed)
        self.update_idx = 0
        self.global_step = 0
        self.episodes = 0
        self.elapsed = 0.0
        self.ep_return = np.zeros(ppo.num_envs, dtype=np.float64)
        self.last_metrics: dict[str, Any] = {}
        self.last_eval: dict[str, float] = {}
        self.best: dict[str, Any] | None = None
        """RunConfig.keep_best: the chosen evaluation (``by``, ``update``, ``global_step`` and
        the eval_* figures); its weights are ``self._best_weights``."""
        self._best_weights: dict[str, torch.Tensor] | None = None
        self._rollout = (ppo.rollout_steps, ppo.num_envs)  # (T', k) of the last collect()
        self._weighted = False  # the last collect() stored selector step weights
        self._writer: Any = None

    # ------------------------------------------------------------------ rollout
    def rollout_plan(self) -> tuple[int, int]:
        """(T', k): time steps of the next rollout and how many envs act in its last step.

        A full rollout is (T, B). When less than T * B steps of the step budget are left, the
        rollout is shortened to ceil(left / B) steps and only the first k envs act in the
        last one (the others stay frozen), so training ends at exactly ``total_steps``."""
        t, b = self.buffer.steps, self.ppo.num_envs
        total = self.run.total_steps
        left = t * b if total is None else min(t * b, max(total - self.global_step, 0))
        steps = max(1, math.ceil(left / b))
        return steps, max(0, left - (steps - 1) * b)

    @torch.inference_mode()
    def collect(self) -> dict[str, float]:
        """Run T steps of the B envs with the current policy into the buffer (Alg. 3.3 l. 3-10);
        the last rollout of a step budget is shorter (see ``rollout_plan``)."""
        env, buf, b = self.env, self.buffer, self.ppo.num_envs
        steps, last_envs = self.rollout_plan()
        self._rollout = (steps, last_envs)
        found, length, cost, returns = [], [], [], []
        if hasattr(self.selector, "set_progress") and self.run.total_steps:
            self.selector.set_progress(self.global_step / self.run.total_steps)  # MEDC rate_end
        self._weighted = False  # any step weight from the selector in this rollout
        for t in range(steps):
            actor_obs, critic_obs = self.observer.observe(env)
            a_obs = buf.actor_obs[t]
            a_obs.copy_(torch.as_tensor(actor_obs))
            buf.critic_obs[t].copy_(torch.as_tensor(critic_obs))
            mask = buf.masks[t]
            mask.copy_(torch.from_numpy(self.head.policy_mask(env.action_mask())))
            actions, logp = policy_step(self.agent, a_obs, mask, self.selector, env)
            buf.actions[t] = actions
            buf.logp[t] = logp
            weights = step_weights(self.selector, b)
            if weights is not None:
                buf.weights[t] = torch.from_numpy(np.asarray(weights, dtype=np.float32))
                self._weighted = True
            buf.values[t] = self.agent.value(buf.critic_obs[t]).reshape(b)
            frozen = t == steps - 1 and last_envs < b
            if frozen:  # inactive envs do not step (their actions are not checked or applied)
                env.active[last_envs:] = False
            try:
                res = env.step(self.head.env_actions(actions.numpy()))
            finally:
                if frozen:
                    env.active[last_envs:] = True
            buf.rewards[t] = torch.from_numpy(np.asarray(res.reward, dtype=np.float32))
            if self.ppo.reward_scale != 1.0:
                buf.rewards[t] *= self.ppo.reward_scale
            buf.dones[t] = torch.from_numpy(np.asarray(res.terminated | res.truncated))
            self.ep_return += res.reward
            ep = res.episode
            if ep is not None and len(ep.index):
                found.append(ep.found)
                length.append(ep.length)
                cost.append(ep.cost)
                returns.append(self.ep_return[ep.index].copy())
                self.ep_return[ep.index] = 0.0
                self.selector.episode_start(ep.index)
        _, critic_obs = self.observer.observe(env)
        self.last_value = self.agent.value(torch.as_tensor(critic_obs)).reshape(b).clone()
        self.global_step += (steps - 1) * b + last_envs
        n = int(sum(len(x) for x in found))
        self.episodes += n
        if n == 0:
            return {"episodes": 0, "success": math.nan, "episode_length": math.nan,
                    "episode_cost": math.nan, "episode_return": math.nan}
        return {"episodes": n,
                "success": float(np.concatenate(found).mean()),
                "episode_length": float(np.concatenate(length).mean()),
                "episode_cost": float(np.concatenate(cost).mean()),
                "episode_return": float(np.concatenate(returns).mean())}

    # ------------------------------------------------------------------ update
    def learning_rate(self) -> float:
        """Current step size; linear anneal to 0 over the step budget if enabled."""
        lr = self.ppo.learning_rate
        if self.ppo.anneal_lr and self.run.total_steps:
            updates = math.ceil(self.run.total_steps / self.ppo.batch_steps)
            lr *= max(0.0, 1.0 - self.update_idx / updates)
        return lr

    def update(self) -> dict[str, float]:
        """GAE (Eq. 3) then epochs of minibatch steps on the loss of Eq. 4 (Alg. 3.3 l. 12-13)."""
        cfg, buf, agent = self.ppo, self.buffer, self.agent
        for group in self.optimizer.param_groups:
            group["lr"] = self.learning_rate()
        t, k = self._rollout
        rewards, values, dones = buf.rewards[:t], buf.values[:t], buf.dones[:t]
        advantages, returns = gae(rewards, values, dones, self.last_value, cfg.gamma,
                                  cfg.gae_lambda)
        b, n = buf.actions.shape[1:]
        if k < b:  # envs frozen in the last step end at t - 1, bootstrapped with V(s_{t-1})
            adv_f, ret_f = gae(rewards[:t - 1, k:], values[:t - 1, k:], dones[:t - 1, k:],
                               values[t - 1, k:], cfg.gamma, cfg.gae_lambda)
            advantages[:t - 1, k:], returns[:t - 1, k:] = adv_f, ret_f
        m = (t - 1) * b + k  # samples collected: time-major, the first k envs of the last step
        # flatten time and envs; agents stay together so one env step = 1 value + n actor samples
        b_actor = buf.actor_obs[:t].reshape(t * b, n, *buf.actor_obs.shape[3:])[:m]
        b_critic = buf.critic_obs[:t].reshape(t * b, *buf.critic_obs.shape[2:])[:m]
        b_mask = buf.masks[:t].reshape(t * b, n, -1)[:m]
        b_actions = buf.actions[:t].reshape(t * b, n)[:m]
        b_logp = buf.logp[:t].reshape(t * b, n)[:m]
        b_values = values.reshape(t * b)[:m]
        b_adv = advantages.reshape(t * b)[:m]
        b_ret = returns.reshape(t * b)[:m]
        b_weights = buf.weights[:t].reshape(t * b)[:m] if self._weighted else None
        mb_size = math.ceil(m / cfg.num_minibatches)
        sums: dict[str, float] = {}
        count = 0
        for _epoch in range(cfg.update_epochs):
            perm = torch.randperm(m, generator=self.generator)
            for start in range(0, m, mb_size):
                idx = perm[start:start + mb_size]
                k = idx.numel()
                mask = b_mask[idx].reshape(k * n, -1)
                logits = agent.logits(b_actor[idx].reshape(k * n, *b_actor.shape[2:]), mask)
                logp_all = masked_log_probs(logits, mask)
                new_logp = logp_all.gather(-1, b_actions[idx].reshape(k * n, 1)).reshape(k, n)
                entropy = entropy_from_log_probs(logp_all).reshape(k, n)
                adv = b_adv[idx]
                if cfg.norm_adv and k > 1:
                    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                new_values = agent.value(b_critic[idx]).reshape(k)
                losses = ppo_losses(
                    new_logp, b_logp[idx], adv.unsqueeze(1).expand(k, n), new_values,
                    b_ret[idx], entropy, clip_coef=cfg.clip_coef, vf_coef=cfg.vf_coef,
                    ent_coef=cfg.ent_coef, old_values=b_values[idx], clip_vloss=cfg.clip_vloss,
                    weights=None if b_weights is None else b_weights[idx].unsqueeze(1).expand(k, n))
                if not bool(torch.isfinite(losses.loss)):
                    self._diverged(f"the PPO loss is {losses.loss.item()} (policy "
                                   f"{losses.pg_loss.item()}, value {losses.v_loss.item()}, "
                                   f"entropy {losses.entropy.item()})")
                self.optimizer.zero_grad(set_to_none=True)
                losses.loss.backward()
                # actor and critic are separate networks: clip each, so the critic's larger
                # gradients cannot shrink the actor's step through one global norm
                torch.nn.utils.clip_grad_norm_(agent.actor.parameters(), cfg.max_grad_norm)
                torch.nn.utils.clip_grad_norm_(agent.critic.parameters(), cfg.max_grad_norm)
                self.optimizer.step()
                for name, val in losses._asdict().items():
                    sums[name] = sums.get(name, 0.0) + val.item()
                count += 1
            if cfg.target_kl is not None and float(losses.approx_kl) > cfg.target_kl:
                break
        broken = [k for k, p in agent.named_parameters() if not bool(torch.isfinite(p).all())]
        if broken:
            self._diverged(f"the network's weights hold NaN/inf after the update ({broken[:3]})")
        var_ret = float(b_ret.var()) if m > 1 else 0.0  # one sample has no variance
        explained = math.nan if var_ret == 0 else 1.0 - float((b_ret - b_values).var()) / var_ret
        out = {k: v / count for k, v in sums.items()}
        return {"learning_rate": self.optimizer.param_groups[0]["lr"],
                "loss": out["loss"], "policy_loss": out["pg_loss"],
                "value_loss": out["v_loss"], "entropy": out["entropy"],
                "approx_kl": out["approx_kl"], "clipfrac": out["clipfrac"],
                "explained_variance": explained}

    def _diverged(self, what: str) -> None:
        cfg = self.ppo
        raise TrainingDiverged(
            f"training diverged at update {self.update_idx + 1} (env step {self.global_step}): "
            f"{what}; nothing of this update was saved. Lower ppo.learning_rate (now "
            f"{cfg.learning_rate:g}) or ppo.reward_scale (now {cfg.reward_scale:g}), or check "
            f"ppo.ent_coef / vf_coef / adam_eps")

    # ------------------------------------------------------------------ evaluation
    def policy(self, best: bool = False) -> Any:
        """The current actor as a greedy Policy (reset/act), as load_model would return it;
        ``best``: the policy that ``RunConfig.keep_best`` chose instead."""
        from workers.mdrl.modelio import GreedyPolicy

        return GreedyPolicy(self._best_agent() if best else self.agent, self.observer, self.head)

    def keep_if_best(self, evals: dict[str, float]) -> bool:
        """Model selection (``RunConfig.keep_best``): whether the evaluation ``evals`` of the
        current policy beats the best so far; if so its weights and figures become the best,
        and ``out/best`` the model file. Called after each evaluation."""
        if self.run.keep_best is None:
            return False
        keys = KEEP_BEST[self.run.keep_best]

        def rank(figures: dict[str, Any]) -> tuple[float, ...]:
            return tuple(math.inf if figures.get(k) is None or math.isnan(figures[k])
                         else float(figures[k]) for k in keys)

        if self.best is not None and rank(evals) >= rank(self.best):
            return False
        self.best = {"by": self.run.keep_best, "update": self.update_idx,
                     "global_step": self.global_step, **evals}
        self._best_weights = {k: v.detach().clone() for k, v in self.agent.state_dict().items()}
        if self.out is not None:
            self.save_model(self.out / "best", best=True)
        return True

    def _best_agent(self) -> ActorCritic:
        if self._best_weights is None:
            raise ValueError("no best policy: train with RunConfig.keep_best set and at least "
                             "one evaluation")
        agent = copy.deepcopy(self.agent)
        agent.load_state_dict(self._best_weights)
        return agent

    def evaluate(self) -> dict[str, float]:
        """Greedy evaluation on the fixed seeded episodes (does not touch training RNGs)."""
        return greedy_eval(self.policy(), self.env_spec, self.run.eval_episodes,
                           self.run.eval_seed)

    # ------------------------------------------------------------------ loop
    def budget_left(self) -> bool:
        return self.run.budget_left(self.global_step, self.elapsed)

    def _no_time_for_another(self, update_s: float, evaluating: bool = False) -> bool:
        """A time budget (``RunConfig.minutes``, a worker's task deadline) holds the final
        evaluation too: this update is the last when one more update of ``update_s`` and the
        final evaluation would not fit (after this update's own periodic evaluation when
        ``evaluating``). The evaluation's time is the last one measured, before
        the first an upper bound: every episode runs ``max_steps`` at this update's seconds per
        env step (rollout and learning, which a greedy step does not pay) plus the setup of an
        env and observer (an evaluation builds its own: ~1 s at 30 x 30 with route maps)."""
        if self.run.minutes is None:
            return False
        eval_s = self._eval_s
        if eval_s is None:
            per_step = update_s / max(1, self.ppo.batch_steps)
            steps = self.run.eval_episodes * self.env_spec.max_steps
            eval_s = steps * per_step + self._setup_s
        evals = 2 if evaluating else 1
        return self.elapsed + update_s + evals * eval_s > self.run.minutes * 60.0

    checkpoint_interval_s: float = 0.0
    """Seconds per checkpoint that ``train()`` may write on average besides the
    ``RunConfig.checkpoint_every`` rule (0: every ``checkpoint_every`` updates). A subclass
    (the worker's ``JobTrainer``) sets it so a run of tiny updates does not write a checkpoint
    every few milliseconds."""
    checkpoint_burst: int = 10
    """Checkpoints a process may write at once before ``checkpoint_interval_s`` applies (a
    token bucket): the first updates of a run, where a process killed for memory dies, are
    checkpointed as ``checkpoint_every`` says; after that at most one per interval."""
    _checkpoint_tokens: float = 0.0
    _checkpoint_clock: float = 0.0

    def _checkpoint_due(self) -> bool:
        """Whether the update just done gets a checkpoint (the last one always does): every
        ``checkpoint_every`` updates while the bucket holds a token; it holds
        ``checkpoint_burst`` at the start of ``train()`` and gains one per
        ``checkpoint_interval_s`` seconds. So no work older than about one interval and one
        update is ever lost, and tiny updates cost a write per interval, not per update."""
        ce = self.run.checkpoint_every
        if not ce or self.update_idx % ce != 0:
            return False
        wait = self.checkpoint_interval_s
        if wait <= 0:
            return True
        now = _monotonic()
        self._checkpoint_tokens = min(float(self.checkpoint_burst), self._checkpoint_tokens
                                      + (now - self._checkpoint_clock) / wait)
        self._checkpoint_clock = now
        if self._checkpoint_tokens < 1.0:
            return False
        self._checkpoint_tokens -= 1.0
        return True

    def train(self) -> dict[str, Any]:
        """Run updates until the step or time budget is used; returns the last metrics row.
        A time budget ends early enough for the final evaluation (``_no_time_for_another``)."""
        run = self.run
        if run.total_steps is None and run.minutes is None:
            raise ValueError("Trainer.train: give a budget (RunConfig.total_steps and/or minutes)")
        if self.ppo.anneal_lr and run.total_steps is None:
            warnings.warn("anneal_lr needs a step budget; learning rate stays constant",
                          stacklevel=2)
        torch.set_num_threads(run.threads)
        self._open_outputs()
        self._checkpoint_tokens = float(self.checkpoint_burst)  # see _checkpoint_due
        self._checkpoint_clock = _monotonic()
        bar = self._progress_bar()
        t0, elapsed0 = time.perf_counter(), self.elapsed
        more = self.budget_left()
        try:
            while more:
                u0 = time.perf_counter()
                step0 = self.global_step
                episode_stats = self.collect()
                loss_stats = self.update()
                self.update_idx += 1
                # the time this update took counts: a time budget used up by it makes it the
                # last one (final evaluation and checkpoint), as a step budget does
                self.elapsed = elapsed0 + (time.perf_counter() - t0)
                every = run.eval_every
                due = bool(every and self.update_idx % every == 0)  # a periodic evaluation
                last = not self.budget_left() or self._no_time_for_another(
                    time.perf_counter() - u0, evaluating=due)
                more = not last
                evals, kept = {}, False
                if last or due:
                    e0 = time.perf_counter()
                    evals = self.evaluate()
                    self._eval_s = time.perf_counter() - e0
                    self.last_eval = evals
                    kept = self.keep_if_best(evals)
                self.elapsed = elapsed0 + (time.perf_counter() - t0)
                if kept:  # the kept policy's training time (its card's wall_time_s)
                    self.best["wall_time_s"] = self.elapsed
                sps = (self.global_step - step0) / max(time.perf_counter() - u0, 1e-9)
                row = {"update": self.update_idx, "global_step": self.global_step,
                       "wall_time": self.elapsed, "sps": sps,
                       **loss_stats, **episode_stats, **evals}
                self._log(row)
                if bar is not None:
                    bar.update(self.global_step - step0)
                    bar.set_postfix(sps=f"{sps:.0f}", succ=f"{episode_stats['success']:.2f}",
                                    len=f"{episode_stats['episode_length']:.1f}",
                                    eval=f"{self.last_eval.get('eval_success', math.nan):.2f}")
                if self.out is not None and (last or self._checkpoint_due()):
                    self.save_checkpoint(self.out / "checkpoint")
        finally:
            if bar is not None:
                bar.close()
            if self._writer is not None:
                self._writer.close()
                self._writer = None
        if self.out is not None:
            self.save_model(self.out / "model")
            if self.best is not None:  # again: a resumed run may have left a later one there
                self.save_model(self.out / "best", best=True)
        return self.last_metrics

    # ------------------------------------------------------------------ outputs
    def _open_outputs(self) -> None:
        if self.out is None:
            return
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "config.json").write_text(json.dumps(self.config_dict(), indent=1))
        metrics = self.out / "metrics.csv"
        if self.update_idx == 0 or not metrics.exists():
            with metrics.open("w", newline="") as f:
                csv.writer(f).writerow(METRIC_COLUMNS)
        else:  # resumed: drop rows written after the checkpoint we resumed from, a row at a
            # time (a run of tiny updates has millions: held at once, they took the memory)
            tmp = metrics.with_name(metrics.name + ".tmp")
            with metrics.open(newline="") as f, tmp.open("w", newline="") as out:
                rows, keep = csv.reader(f), csv.writer(out)
                keep.writerow(next(rows, METRIC_COLUMNS))
                keep.writerows(r for r in rows if int(r[0]) <= self.update_idx)
            os.replace(tmp, metrics)
        if self.run.tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self._writer = SummaryWriter(str(self.out / "tb"), purge_step=self.global_step or None)
            if self.update_idx == 0:
                text = "\n".join(f"|{k}|{v}|" for k, v in self.config_dict()["ppo"].items())
                self._writer.add_text("hyperparameters", "|param|value|\n|-|-|\n" + text)

    def _progress_bar(self) -> Any:
        if not self.run.progress:
            return None
        from tqdm.auto import tqdm

        return tqdm(total=self.run.total_steps, initial=self.global_step, unit="step",
                    dynamic_ncols=True, desc="train")

    def _log(self, row: dict[str, Any]) -> None:
        self.last_metrics = row
        if self.out is not None:
            with (self.out / "metrics.csv").open("a", newline="") as f:
                csv.writer(f).writerow([_fmt(row.get(c)) for c in METRIC_COLUMNS])
        if self._writer is not None:
            step = self.global_step
            for k in ("loss", "policy_loss", "value_loss", "entropy", "approx_kl", "clipfrac",
                      "explained_variance"):
                self._writer.add_scalar(f"losses/{k}", row[k], step)
            for k in ("learning_rate", "sps", "success", "episode_length", "episode_cost",
                      "episode_return", "eval_success", "eval_time", "eval_cost"):
                if k in row and not (isinstance(row[k], float) and math.isnan(row[k])):
                    self._writer.add_scalar(f"charts/{k}", row[k], step)

    def config_dict(self) -> dict[str, Any]:
        out = {"env": self.env_spec.to_dict(), "observation": self.obs_spec.to_dict(),
               "ppo": self.ppo.to_dict(), "run": self.run.to_dict()}
        if self.observer.embedder is not None:  # which CAE encoder, by weight digest
            out["walls_encoder"] = self.observer.embedder.card
        return out

    def save_model(self, path: str | Path, best: bool = False) -> Path:
        """The final policy as a model file, or with ``best`` the one ``keep_if_best`` chose:
        its card's metrics are that evaluation's, and ``training.selected`` says when it was."""
        from workers.mdrl.modelio import save_model

        metrics = {k: self.last_metrics.get(k) for k in METRIC_COLUMNS if k in self.last_metrics}
        metrics.update(self.last_eval)
        training = {"run": self.run.to_dict(), "env_steps": self.global_step,
                    "updates": self.update_idx, "wall_time_s": self.elapsed}
        agent = self.agent
        if best:
            agent = self._best_agent()
            metrics = {k: v for k, v in self.best.items() if k.startswith("eval_")}
            training.update(env_steps=self.best["global_step"], updates=self.best["update"],
                            wall_time_s=self.best.get("wall_time_s", self.elapsed))
            training["selected"] = {**self.best, "eval_episodes": self.run.eval_episodes,
                                    "eval_seed": self.run.eval_seed}
        if self.init_info is not None:  # fine-tuned: which model's weights it started from
            training["init_from"] = self.init_info
        if hasattr(self.selector, "card"):  # expert-guided training (medc.py) lists its experts
            training["experts"] = self.selector.card()
        return save_model(path, agent, self.env_spec, self.obs_spec, self.ppo,
                          metrics=metrics, observer=self.observer, training=training)

    # ------------------------------------------------------------------ checkpoints
    def save_checkpoint(self, path: str | Path) -> Path:
        """Save at an update boundary everything needed to continue identically."""
        tensors = {f"agent/{k}": v for k, v in self.agent.state_dict().items()}
        opt_tensors, opt_meta = ckpt.optimizer_to_parts(self.optimizer)
        tensors.update(opt_tensors)
        tensors["torch_generator"] = self.generator.get_state()
        tensors["trainer/ep_return"] = torch.from_numpy(self.ep_return.copy())
        if self._best_weights is not None:
            tensors.update({f"best/{k}": v for k, v in self._best_weights.items()})
        env_arrays, env_meta = ckpt.env_state(self.env)
        meta = {**self.config_dict(),
                "counters": {"update": self.update_idx, "global_step": self.global_step,
                             "episodes": self.episodes, "elapsed": self.elapsed},
                "last_eval": self.last_eval, "best": self.best, "optimizer": opt_meta,
                "env_state": env_meta, "init_from": self.init_info,
                # the card's training figures: a run resumed after its last checkpoint runs
                # no update, and its card lost 17 of its 20 metrics
                "last_metrics": {k: v.item() if isinstance(v, np.generic) else v
                                 for k, v in self.last_metrics.items()}}
        extras = self.checkpoint_extras()
        if extras:  # only that kind of trainer can continue it
            meta |= {**extras, "extras_by": type(self).__name__}
        if hasattr(self.selector, "state_dict"):  # e.g. an expert selector's per-episode flags
            meta["selector"] = self.selector.state_dict()  # must be JSON-able
        return ckpt.save_checkpoint(path, tensors, env_arrays, meta)

    def checkpoint_extras(self) -> dict[str, Any]:
        """JSON-able state a subclass adds to its checkpoints' meta (``load_state`` gets it
        back in ``meta``); none here."""
        return {}

    def load_state(self, tensors: dict[str, torch.Tensor], env_arrays: dict[str, np.ndarray],
                   meta: dict[str, Any]) -> None:
        """Restore a checkpoint into this trainer (built with the checkpoint's configs)."""
        by = meta.get("extras_by")
        if by and type(self).checkpoint_extras is Trainer.checkpoint_extras:
            raise ValueError(f"checkpoint holds the state of a {by} run; resume it with "
                             f"{by}.resume, not as plain PPO")
        c = meta["counters"]
        kinds = {"update": int, "global_step": int, "episodes": int, "elapsed": (int, float)}
        wrong = [k for k, kind in kinds.items() if not isinstance(c.get(k), kind)
                 or isinstance(c.get(k), bool) or not c[k] >= 0]
        if wrong:
            raise ValueError(f"checkpoint counters {wrong} are not numbers >= 0 (a damaged "
                             "state.json)")
        sd = {k[len("agent/"):]: v for k, v in tensors.items() if k.startswith("agent/")}
        try:
            self.agent.load_state_dict(sd)
        except RuntimeError as exc:  # the weights are of another network than state.json says
            from workers.mdrl.cae import error_text

            raise ValueError(f"checkpoint weights do not fit its configuration: "
                             f"{error_text(exc)}") from None
        ckpt.optimizer_from_parts(self.optimizer, tensors, meta["optimizer"])
        self.generator.set_state(tensors["torch_generator"])
        self.ep_return = tensors["trainer/ep_return"].numpy().copy()
        ckpt.restore_env_state(self.env, env_arrays, meta["env_state"])
        self.update_idx, self.global_step = c["update"], c["global_step"]
        self.episodes, self.elapsed = c["episodes"], c["elapsed"]
        self.last_eval = meta.get("last_eval", {})
        last = meta.get("last_metrics")
        self.last_metrics = dict(last) if isinstance(last, dict) else {}
        self.best = meta.get("best")
        best = {k[len("best/"):]: v for k, v in tensors.items() if k.startswith("best/")}
        self._best_weights = best or None
        if self.best is not None and self.best.get("by") != self.run.keep_best:
            self.best, self._best_weights = None, None  # resumed with another rule: choose anew
        self.init_info = meta.get("init_from")
        if "selector" in meta:
            if not hasattr(self.selector, "load_state_dict"):
                raise ValueError("checkpoint holds an action-selector state; pass the same kind "
                                 "of selector (with load_state_dict) to resume")
            self.selector.load_state_dict(meta["selector"])

    @classmethod
    def resume(cls, path: str | Path, out: str | Path | None = None,
               run_overrides: dict[str, Any] | None = None,
               selector: ActionSelector | None = None,
               walls_encoder: Any = None, **build: Any) -> Trainer:
        """Rebuild a trainer from a checkpoint dir (or a run dir holding `checkpoint/`).
        ``build``: what a subclass's constructor needs besides the configs (e.g. experts)."""
        path = Path(path)
        if path.name != "checkpoint" and ckpt.restore_swapped(path / "checkpoint"):
            log.warning("%s: resuming from checkpoint.old (killed while saving the next one)",
                        path)
        if (path / "checkpoint").is_dir():
            path = path / "checkpoint"
        tensors, env_arrays, meta = ckpt.load_checkpoint(path)
        parts = {"run": dict, "env": dict, "ppo": dict, "observation": dict, "counters": dict,
                 "optimizer": dict, "env_state": dict}
        bad = [k for k, kind in parts.items() if not isinstance(meta.get(k), kind)]
        if bad:
            raise ValueError(f"checkpoint {path}: state.json lacks {bad} (not a checkpoint of "
                             f"a {cls.__name__} run, or a damaged one)")
        run = RunConfig.from_dict({**meta["run"], **(run_overrides or {})})
        env_spec, ppo = EnvSpec.from_dict(meta["env"]), PPOConfig.from_dict(meta["ppo"])
        obs_spec = ObservationSpec.from_dict(meta["observation"])
        trainer = cls(env_spec, obs_spec, ppo, run,
                      out=out if out is not None else path.parent, selector=selector,
                      walls_encoder=walls_encoder, _resuming=True, **build)
        saved = meta.get("walls_encoder", {}).get("digest")
        embedder = trainer.observer.embedder
        if saved is not None and (embedder is None or embedder.card["digest"] != saved):
            raise ValueError(f"checkpoint {path} was trained with walls encoder {saved}; "
                             f"{obs_spec.walls_embedding!r} now holds another one")
        trainer.load_state(tensors, env_arrays, meta)
        trainer._check_same_run()
        return trainer

    def _check_same_run(self) -> None:
        """Resuming writes into the run directory: refuse when what it holds is not this
        checkpoint's run (another run's checkpoint copied in), since the curve would splice two
        runs together. config.json must name the same env, observation, PPO and seed, and the
        metrics.csv row of the checkpoint's update the same env step."""
        if self.out is None:
            return
        mine = self.config_dict()
        try:
            theirs = json.loads((self.out / "config.json").read_text())
        except (OSError, ValueError):
            theirs = None  # none yet (a fresh --out) or unreadable: nothing to compare
        if isinstance(theirs, dict):
            parsers = {"env": EnvSpec, "observation": ObservationSpec, "ppo": PPOConfig}
            differ = []
            for key, kind in parsers.items():
                try:  # through the type: a file from before a field existed gets its default
                    same = kind.from_dict(theirs.get(key)).to_dict() == mine[key]
                except (TypeError, ValueError, KeyError, AttributeError):
                    same = False
                if not same:
                    differ.append(key)
            if (theirs.get("run") or {}).get("seed", mine["run"]["seed"]) != mine["run"]["seed"]:
                differ.append("run.seed")
            if differ:
                raise ValueError(f"{self.out}/config.json is another run's ({', '.join(differ)} "
                                 "differ from the checkpoint's): resume into another --out")
        metrics = self.out / "metrics.csv"
        if not metrics.is_file() or self.update_idx == 0:
            return
        with metrics.open(newline="") as f:
            for row in csv.DictReader(f):
                if row.get("update") == str(self.update_idx):
                    if row.get("global_step") != str(self.global_step):
                        raise ValueError(
                            f"{metrics} is not this checkpoint's run: its update "
                            f"{self.update_idx} was at env step {row.get('global_step')}, the "
                            f"checkpoint's at {self.global_step}; resume into another --out")
                    return


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    return str(v)
