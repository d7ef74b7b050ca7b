"""PPO pieces (Eq. 2-4): hyperparameters, GAE and the clipped loss, as pure functions.

The trainer (`train.py`) wires them together; tests call them directly on hand-made numbers.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass
from typing import Any, NamedTuple

import torch

MAX_HORIZON = 1 << 22
"""Largest horizon (env steps per update; the presets use at most 8,192): a config's 1e12 ended
in an allocation error naming no field."""
MAX_NUM_ENVS = 1 << 14
"""Largest number of environments stepped together (the presets use at most 128)."""
MAX_UPDATE_EPOCHS = 10_000
"""Most passes over a rollout per update (Table 3.2: 50; the task spec allows 100): an update
cannot be stopped by --minutes, so a config's 10^12 trained one update forever."""
MAX_LEARNING_RATE = 1e30
"""Largest learning rate: Adam's step (lr / bias correction) must stay a float32; 1e39 (or
1e300) crashed the first optimizer step with a traceback instead of naming the field. Rates
far below it but too large (1e10) are not refused: the run stops with "training diverged",
which names learning_rate."""
MAX_CLIP_COEF = 10.0
"""Largest PPO clip epsilon (any epsilon >= 1 already leaves the ratio's lower side open): the
clamp's bounds must stay float32; 1e300 crashed the first update with a traceback."""


@dataclass
class PPOConfig:
    """PPO hyperparameters. Defaults are Table 3.2 of the thesis; the rest are ours."""

    learning_rate: float = 3e-4
    """Adam step size (Table 3.2)."""
    clip_coef: float = 0.2
    """PPO clipping parameter epsilon of Eq. 2 (Table 3.2)."""
    ent_coef: float = 0.01
    """Entropy coefficient c2 of Eq. 4 (Table 3.2)."""
    gamma: float = 0.99
    """Discount factor gamma of Eq. 3 (Table 3.2)."""
    gae_lambda: float = 0.95
    """GAE discount lambda of Eq. 3 (Table 3.2)."""
    horizon: int = 4000
    """Env steps per update H, summed over the batched envs (Table 3.2)."""
    update_epochs: int = 50
    """Passes over the rollout per update (Table 3.2)."""
    vf_coef: float = 0.5
    """Value-loss coefficient c1 of Eq. 4."""
    num_minibatches: int = 4
    """Minibatches per epoch; the env steps of one update are split into this many."""
    max_grad_norm: float = 0.5
    """Global gradient-norm clip."""
    num_envs: int = 40
    """Environments stepped together (B); rollout length is ceil(horizon / num_envs)."""
    anneal_lr: bool = False
    """Linearly decay the learning rate to 0 over the step budget (needs a step budget)."""
    norm_adv: bool = True
    """Normalise advantages per minibatch."""
    clip_vloss: bool = False
    """Clip the value update around the old values (as the policy ratio)."""
    target_kl: float | None = None
    """Stop the epochs of an update early when the approximate KL exceeds this."""
    adam_eps: float = 1e-5
    """Adam epsilon."""
    reward_scale: float = 1.0
    """Multiplies the team reward before GAE (keeps value targets O(1); metrics stay unscaled)."""

    def __post_init__(self) -> None:
        _check_types(self)
        checks = {
            "learning_rate": (0 < self.learning_rate <= MAX_LEARNING_RATE,
                              f"in (0, {MAX_LEARNING_RATE:g}]"),
            "clip_coef": (0 < self.clip_coef <= MAX_CLIP_COEF, f"in (0, {MAX_CLIP_COEF:g}]"),
            # a negative c1 maximises the value error, a negative c2 rewards certainty: both
            # trained silently (the task spec already refuses them)
            "ent_coef": (self.ent_coef >= 0, ">= 0"),
            "vf_coef": (self.vf_coef >= 0, ">= 0"),
            "gamma": (0.0 <= self.gamma <= 1.0, "in [0, 1]"),
            "gae_lambda": (0.0 <= self.gae_lambda <= 1.0, "in [0, 1]"),
            "horizon": (1 <= self.horizon <= MAX_HORIZON, f"in 1..{MAX_HORIZON}"),
            "update_epochs": (1 <= self.update_epochs <= MAX_UPDATE_EPOCHS,
                              f"in 1..{MAX_UPDATE_EPOCHS}"),
            "num_minibatches": (self.num_minibatches >= 1, ">= 1"),
            "num_envs": (1 <= self.num_envs <= MAX_NUM_ENVS, f"in 1..{MAX_NUM_ENVS}"),
            "max_grad_norm": (self.max_grad_norm > 0, "> 0"),
            "reward_scale": (self.reward_scale > 0, "> 0"),
            "adam_eps": (self.adam_eps > 0, "> 0"),
            "target_kl": (self.target_kl is None or self.target_kl > 0, "> 0 or None"),
        }
        bad = [k for k, (ok, _) in checks.items() if not ok]
        if bad:
            raise ValueError(f"PPOConfig: invalid value for {bad}: "
                             + ", ".join(f"{k}={getattr(self, k)!r} (must be {checks[k][1]})"
                                         for k in bad))

    # -- derived values (computed here only) --
    @property
    def rollout_steps(self) -> int:
        """Derived: time steps T per env per update, ceil(horizon / num_envs)."""
        return math.ceil(self.horizon / self.num_envs)

    @property
    def batch_steps(self) -> int:
        """Derived: env steps actually collected per update, T * B (>= horizon)."""
        return self.rollout_steps * self.num_envs

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PPOConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"PPOConfig: unknown field(s) {unknown}; known: {sorted(names)}")
        return cls(**d)


_INT_FIELDS = ("horizon", "update_epochs", "num_minibatches", "num_envs")
_BOOL_FIELDS = ("anneal_lr", "norm_adv", "clip_vloss")
_REAL_FIELDS = ("learning_rate", "clip_coef", "ent_coef", "gamma", "gae_lambda", "vf_coef",
                "max_grad_norm", "adam_eps", "reward_scale", "target_kl")


def _check_types(cfg: PPOConfig) -> None:
    """ValueError naming the field when a config file gives a value of the wrong type or a
    non-finite number (``horizon = 100.5``, ``learning_rate = "fast"``, ``ent_coef = NaN``),
    before a comparison fails with a TypeError or NaN slips through it. bool is neither an
    integer nor a number here."""
    for name in _INT_FIELDS:
        v = getattr(cfg, name)
        if isinstance(v, bool) or not isinstance(v, numbers.Integral):
            raise ValueError(f"PPOConfig: {name} must be an integer, got {v!r}")
    for name in _BOOL_FIELDS:
        v = getattr(cfg, name)
        if not isinstance(v, bool):
            raise ValueError(f"PPOConfig: {name} must be true or false, got {v!r}")
    for name in _REAL_FIELDS:
        v = getattr(cfg, name)
        if v is None and name == "target_kl":
            continue
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
            raise ValueError(f"PPOConfig: {name} must be a finite number, got {v!r}")


def gae(
    rewards: torch.Tensor,
    values: torch.Tensor,
    dones: torch.Tensor,
    last_value: torch.Tensor,
    gamma: float,
    lam: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Generalized Advantage Estimate over a rollout (Eq. 3), returns (advantages, returns).

    Time-first tensors `[T, ...]`: `rewards[t]`, `values[t] = V(s_t)`, and `dones[t]` true when
    the episode ended with the step taken at t (so s_{t+1} belongs to a new episode and is not
    bootstrapped). `last_value = V(s_T)` bootstraps the unfinished tail. The sum of Eq. 3 stops
    at the horizon and at episode ends. Truncated episodes are treated as ended.
    """
    rewards = torch.as_tensor(rewards)
    values = torch.as_tensor(values, dtype=rewards.dtype)
    dones = torch.as_tensor(dones)
    last_value = torch.as_tensor(last_value, dtype=rewards.dtype)
    if rewards.shape != values.shape or rewards.shape != dones.shape:
        raise ValueError(f"gae: rewards {tuple(rewards.shape)}, values {tuple(values.shape)} and "
                         f"dones {tuple(dones.shape)} must have the same [T, ...] shape")
    if last_value.shape != rewards.shape[1:]:
        raise ValueError(f"gae: last_value shape {tuple(last_value.shape)} must be "
                         f"{tuple(rewards.shape[1:])}")
    not_done = 1.0 - dones.to(rewards.dtype)
    advantages = torch.zeros_like(rewards)
    running = torch.zeros_like(last_value)
    next_value = last_value
    for t in range(rewards.shape[0] - 1, -1, -1):
        delta = rewards[t] + gamma * next_value * not_done[t] - values[t]  # TD residual, Eq. 3
        running = delta + gamma * lam * not_done[t] * running
        advantages[t] = running
        next_value = values[t]
    return advantages, advantages + values


class PPOLosses(NamedTuple):
    """Terms of Eq. 4 for one minibatch, plus diagnostics."""

    loss: torch.Tensor
    """Scalar to minimise: -L_clip + c1 * L_vf - c2 * S (Eq. 4 negated)."""
    pg_loss: torch.Tensor
    """-L_clip (Eq. 2)."""
    v_loss: torch.Tensor
    """L_vf = mean (V - V_targ)^2."""
    entropy: torch.Tensor
    """Mean policy entropy S."""
    approx_kl: torch.Tensor
    """KL(old || new) estimate, mean((r - 1) - log r); diagnostic only."""
    clipfrac: torch.Tensor
    """Fraction of samples whose ratio left [1 - eps, 1 + eps]; diagnostic only."""


def ppo_losses(
    new_logp: torch.Tensor,
    old_logp: torch.Tensor,
    advantages: torch.Tensor,
    new_values: torch.Tensor,
    returns: torch.Tensor,
    entropy: torch.Tensor,
    *,
    clip_coef: float,
    vf_coef: float,
    ent_coef: float,
    old_values: torch.Tensor | None = None,
    clip_vloss: bool = False,
    weights: torch.Tensor | None = None,
) -> PPOLosses:
    """The clipped PPO objective (Eq. 2) with value loss and entropy bonus (Eq. 4).

    Policy tensors (`new_logp`, `old_logp`, `advantages`, `entropy`) share one shape (for
    CLDE: one entry per agent sample); value tensors (`new_values`, `returns`) share another
    (one entry per env step, the centralized critic). Advantages are used as given
    (normalise before calling if wanted). ``weights`` (policy shape, optional) scales each
    sample's clipped surrogate; the mean still runs over all samples, so weight 0 drops a
    sample from the policy gradient (expert probation, ``medc.DemonstrationSelector``).
    """
    if not (new_logp.shape == old_logp.shape == advantages.shape == entropy.shape):
        raise ValueError("ppo_losses: new_logp, old_logp, advantages, entropy shapes differ: "
                         f"{tuple(new_logp.shape)}, {tuple(old_logp.shape)}, "
                         f"{tuple(advantages.shape)}, {tuple(entropy.shape)}")
    if new_values.shape != returns.shape:
        raise ValueError(f"ppo_losses: new_values {tuple(new_values.shape)} and returns "
                         f"{tuple(returns.shape)} differ")
    log_ratio = new_logp - old_logp
    ratio = log_ratio.exp()  # r_t(theta) of Eq. 2
    surrogate = torch.min(ratio * advantages,
                          ratio.clamp(1.0 - clip_coef, 1.0 + clip_coef) * advantages)
    if weights is not None:
        if weights.shape != surrogate.shape:
            raise ValueError(f"ppo_losses: weights {tuple(weights.shape)} differ from the "
                             f"policy samples {tuple(surrogate.shape)}")
        surrogate = surrogate * weights
    pg_loss = -surrogate.mean()
    if clip_vloss:
        if old_values is None:
            raise ValueError("ppo_losses: clip_vloss=True needs old_values")
        clipped = old_values + (new_values - old_values).clamp(-clip_coef, clip_coef)
        v_loss = torch.max((new_values - returns) ** 2, (clipped - returns) ** 2).mean()
    else:
        v_loss = ((new_values - returns) ** 2).mean()
    ent = entropy.mean()
    loss = pg_loss + vf_coef * v_loss - ent_coef * ent  # Eq. 4, negated for a minimiser
    with torch.no_grad():
        approx_kl = ((ratio - 1.0) - log_ratio).mean()
        clipfrac = ((ratio - 1.0).abs() > clip_coef).float().mean()
    return PPOLosses(loss, pg_loss, v_loss, ent, approx_kl, clipfrac)


MASKED_LOGP = -1e8
"""Log-probability given to an invalid action (its probability is exactly 0 in float32)."""


def masked_log_probs(logits: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Log-softmax over the valid actions only; invalid ones get MASKED_LOGP (-1e8: exp is 0,
    and 0 * -1e8 keeps the entropy finite). The softmax runs with -inf at the invalid actions:
    a finite fill was no mask for a policy whose valid logits all lie below it (finite weights
    of -1e10 made `drlaas eval` pick invalid moves), and it is the same for every other one."""
    logp = torch.log_softmax(logits.masked_fill(~mask, float("-inf")), dim=-1)
    return torch.where(mask, logp, torch.full_like(logp, MASKED_LOGP))


def entropy_from_log_probs(logp_all: torch.Tensor) -> torch.Tensor:
    """Entropy of a categorical given its (masked) log-probabilities; masked actions add 0."""
    return -(logp_all.exp() * logp_all).sum(-1)
