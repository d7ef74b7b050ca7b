"""Actor and critic CNNs of Table 3.1 (thesis line 482), shared by CMTL, DMTL and ODMTL.

Both networks are the LeNet-like stack of Fig. 3.2; only the input maps and the output size
differ (A**N joint actions for the CMTL actor, A for the shared CLDE actor, 1 for critics).
Max pooling uses ``ceil_mode=True`` so a 3 x 3 ODMTL input pools to 2 x 2, which is what
reproduces the actor sizes of Table 3.4 (4229 parameters for ODMTL with one agent).

With a walls embedding (Ch. 4, Fig. 4.4) the d-vector arrives in the last planes of the input
stack (``observations`` module doc); it skips the convolutions and is concatenated to the
flattened conv features before the fully connected layers.
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import nn
from torch.distributions import Categorical

MASKED_LOGIT = -1e8
"""Logit of an invalid action: its softmax probability is exactly 0 in float32."""


def _init(layer: nn.Module, gain: float) -> nn.Module:
    nn.init.orthogonal_(layer.weight, gain)
    nn.init.zeros_(layer.bias)
    return layer


class LeNet(nn.Module):
    """conv3x3x8 (pad 1) ReLU -> maxpool 2/2 (ceil) -> conv3x3x16 (pad 1) ReLU -> fc32 ReLU ->
    fc16 ReLU -> ``outputs`` (Table 3.1). Orthogonal init, gain sqrt 2; the head uses
    ``head_gain`` (0.01 for actors: near-uniform initial policy; 1 for critics).
    ``embedding`` = d > 0: the last ceil(d / (H * W)) input planes carry a d-vector (Fig. 4.4)."""

    def __init__(self, in_shape: tuple[int, int, int], outputs: int, head_gain: float = 1.0,
                 embedding: int = 0):
        super().__init__()
        c, h, w = (int(x) for x in in_shape)
        if min(c, h, w, outputs) < 1:
            raise ValueError(
                f"LeNet needs a positive (C, H, W) and outputs, got {in_shape}, {outputs}"
            )
        self.in_shape, self.outputs = (c, h, w), int(outputs)
        self.embedding = int(embedding)
        self.code_planes = -(-self.embedding // (h * w))
        if self.code_planes >= c:
            raise ValueError(f"LeNet input {in_shape} has no map planes besides the "
                             f"{self.code_planes} that carry the d = {self.embedding} embedding")
        relu = math.sqrt(2.0)
        flat = 16 * math.ceil(h / 2) * math.ceil(w / 2) + self.embedding
        self.net = nn.Sequential(
            _init(nn.Conv2d(c - self.code_planes, 8, 3, stride=1, padding=1), relu),
            nn.ReLU(),
            nn.MaxPool2d(2, 2, ceil_mode=True),
            _init(nn.Conv2d(8, 16, 3, stride=1, padding=1), relu),
            nn.ReLU(),
            nn.Flatten(),
            _init(nn.Linear(flat, 32), relu),
            nn.ReLU(),
            _init(nn.Linear(32, 16), relu),
            nn.ReLU(),
            _init(nn.Linear(16, self.outputs), head_gain),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (..., C, H, W) -> (..., outputs); any number of leading dims (e.g. B, N)."""
        if tuple(x.shape[-3:]) != self.in_shape:
            raise ValueError(f"LeNet expects inputs (..., {self.in_shape}), got {tuple(x.shape)}")
        lead = x.shape[:-3]
        x = x.reshape((-1,) + self.in_shape)
        if self.embedding:
            maps, planes = x[:, : -self.code_planes], x[:, -self.code_planes:]
            code = planes.reshape(len(x), -1)[:, : self.embedding]
            x = self.net[6:](torch.cat([self.net[:6](maps), code], dim=1))
        else:
            x = self.net(x)
        return x.reshape(lead + (self.outputs,))


class ActorCritic(nn.Module):
    """Actor (policy logits) and centralized critic (state value) of Table 3.1.

    Two ways to build one:
    ``ActorCritic(actor_shape, critic_shape, actor_outputs)`` or
    ``ActorCritic(observer, actor_outputs)`` (shapes from an ``observations.Observer``).
    ``actor_outputs`` is the size of the actor's output (A**N for CMTL, A otherwise);
    ``ActorCritic.for_observer(observer, num_actions)`` takes the per-agent A instead.
    """

    def __init__(self, actor_shape: Any, critic_shape: Any, actor_outputs: int | None = None,
                 embedding: int = 0):
        super().__init__()
        if hasattr(actor_shape, "actor_shape"):  # ActorCritic(observer, actor_outputs)
            if actor_outputs is not None:
                raise ValueError("ActorCritic(observer, actor_outputs) takes two arguments")
            observer, actor_outputs = actor_shape, critic_shape
            actor_shape, critic_shape = observer.actor_shape, observer.critic_shape
            embedding = getattr(observer, "embedding", 0)
        elif actor_outputs is None:
            raise ValueError(
                "ActorCritic needs (actor_shape, critic_shape, actor_outputs) or "
                "(observer, actor_outputs)"
            )
        self.actor = LeNet(actor_shape, int(actor_outputs), head_gain=0.01, embedding=embedding)
        self.critic = LeNet(critic_shape, 1, head_gain=1.0, embedding=embedding)

    @classmethod
    def for_observer(cls, observer: Any, num_actions: int) -> ActorCritic:
        """Networks sized for an ``observations.Observer``; ``num_actions`` per agent (A)."""
        return cls(observer.actor_shape, observer.critic_shape,
                   observer.num_actor_outputs(num_actions), getattr(observer, "embedding", 0))

    def logits(self, actor_obs: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """actor_obs (..., C, H, W), mask bool (..., A) -> logits (..., A), invalid = -1e8."""
        logits = self.actor(actor_obs)
        if mask is None:
            return logits
        if mask.shape != logits.shape:
            raise ValueError(
                f"mask shape {tuple(mask.shape)} must equal logits shape {tuple(logits.shape)}"
            )
        return torch.where(mask.bool(), logits, torch.full_like(logits, MASKED_LOGIT))

    def dist(self, actor_obs: torch.Tensor, mask: torch.Tensor | None = None) -> Categorical:
        """The policy pi(a | o) as a Categorical over the (masked) actions."""
        return Categorical(logits=self.logits(actor_obs, mask))

    def value(self, critic_obs: torch.Tensor) -> torch.Tensor:
        """critic_obs (..., C, H, W) -> V (...) used in the advantage (Eq. 3)."""
        return self.critic(critic_obs).squeeze(-1)
