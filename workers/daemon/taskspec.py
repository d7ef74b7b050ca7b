"""The off-chain task spec (platform.md, "Task spec"): what a worker trains and for how long.

The gateway stores the spec JSON in the content store and puts its CID in the task's on-chain
description; the worker fetches it by that CID (so the bytes are verified) and builds the MDRL
configs from it. Fields: ``env`` (EnvSpec dict), ``observation`` ({kind, window, walls}),
``budget`` ({steps, minutes}), ``seed``, optional ``preset`` (base settings) and ``ppo``
(PPOConfig overrides). Unknown fields of the platform (payment, thresholds...) are ignored here.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from typing import Any

from workers.mdrl.observations import ObservationSpec
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.presets import FAST_PPO, get_preset
from workers.mdrl.spec import EnvSpec

#: Spec documents larger than this are refused before parsing.
MAX_SPEC_BYTES = 256 * 1024
#: A worker never trains longer than this, whatever the spec says (the deadline caps it too).
MAX_MINUTES = 24 * 60.0


class SpecError(ValueError):
    """A task spec that cannot be trained; the message names the field."""


@dataclass(frozen=True)
class TrainingSpec:
    env: EnvSpec
    observation: ObservationSpec
    ppo: PPOConfig
    steps: int | None
    minutes: float | None
    seed: int


def _small_ppo(steps: int | None) -> dict[str, Any]:
    """Keep an update no larger than a quarter of a small step budget, so a tiny budget still
    gives several updates (and so checkpoints and progress points)."""
    ppo = dict(FAST_PPO)
    if steps is not None and steps < 4 * ppo["horizon"]:
        envs = 16 if steps < 4096 else 32
        ppo.update(num_envs=envs, horizon=max(envs, steps // 4 // envs * envs), update_epochs=2)
    return ppo


def parse_spec(raw: bytes | str | dict[str, Any]) -> TrainingSpec:
    """Validate a task spec document; :class:`SpecError` names the bad field."""
    if isinstance(raw, bytes | str):
        if len(raw) > MAX_SPEC_BYTES:
            raise SpecError(f"task spec: {len(raw)} bytes > limit of {MAX_SPEC_BYTES}")
        try:
            doc = json.loads(raw)
        except ValueError as exc:
            raise SpecError(f"task spec: not JSON ({exc})") from None
    else:
        doc = raw
    if not isinstance(doc, dict):
        raise SpecError("task spec: expected a JSON object")
    base = None
    if doc.get("preset"):
        try:
            base = get_preset(str(doc["preset"]))
        except ValueError as exc:
            raise SpecError(f"task spec.preset: {exc}") from None
    env_doc = doc.get("env", {})
    if not isinstance(env_doc, dict):
        raise SpecError("task spec.env: expected an object of EnvSpec fields")
    try:
        env = EnvSpec.from_dict({**(base.env.to_dict() if base else {}), **env_doc})
    except (ValueError, TypeError, KeyError) as exc:
        raise SpecError(f"task spec.env: {exc}") from None
    obs_doc = doc.get("observation", {})
    if not isinstance(obs_doc, dict):
        raise SpecError("task spec.observation: expected {kind, window}")
    try:
        obs = ObservationSpec.from_dict({**(base.observation.to_dict() if base else {}), **obs_doc})
    except (ValueError, TypeError) as exc:
        raise SpecError(f"task spec.observation: {exc}") from None
    budget = doc.get("budget", {})
    if not isinstance(budget, dict):
        raise SpecError("task spec.budget: expected {steps, minutes}")
    steps, minutes = budget.get("steps"), budget.get("minutes")
    if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
        raise SpecError(f"task spec.budget.steps: expected a positive integer, got {steps!r}")
    if minutes is not None and (
        isinstance(minutes, bool) or not isinstance(minutes, int | float) or minutes <= 0
    ):
        raise SpecError(f"task spec.budget.minutes: expected a positive number, got {minutes!r}")
    if steps is None and minutes is None:
        raise SpecError("task spec.budget: give steps and/or minutes")
    if minutes is not None:
        minutes = min(float(minutes), MAX_MINUTES)
    seed = doc.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SpecError(f"task spec.seed: expected a non-negative integer, got {seed!r}")
    ppo_doc = doc.get("ppo", {})
    if not isinstance(ppo_doc, dict):
        raise SpecError("task spec.ppo: expected an object of PPOConfig fields")
    try:
        ppo = PPOConfig.from_dict(
            {**(base.ppo.to_dict() if base else _small_ppo(steps)), **ppo_doc}
        )
    except (ValueError, TypeError) as exc:
        raise SpecError(f"task spec.ppo: {exc}") from None
    return TrainingSpec(env, obs, ppo, steps, minutes, seed)


def spec_document(spec: TrainingSpec) -> dict[str, Any]:
    """The JSON document of ``spec`` (round-trips through :func:`parse_spec`)."""
    return {
        "env": spec.env.to_dict(),
        "observation": spec.observation.to_dict(),
        "ppo": dataclasses.asdict(spec.ppo),
        "budget": {"steps": spec.steps, "minutes": spec.minutes},
        "seed": spec.seed,
    }
