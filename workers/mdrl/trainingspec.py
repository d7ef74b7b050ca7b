"""The training task spec: the one type the gateway, the worker, the CLI and the UI share.

A task's spec is a JSON document (docs/platform.md, "Task spec") stored in the content store;
its CID is the task's on-chain description. ``TrainingSpec.from_dict`` is the only parser of
it: every field is checked against the bounds below (:mod:`workers.mdrl.specfields`), cross-field
rules after that, and a :class:`SpecError` names the dotted field that is wrong.
``trainingspec_json_schema()`` publishes the same bounds as JSON Schema (the gateway puts it in
its OpenAPI document for the task-creation body).

Bounds are platform policy on top of what the MDRL core can compute: they keep one task's
arrays and float math finite. The expected reading of Eq. 6 is
``I * dwell * area / (4 pi d^2)`` with d at least half a cell; with the bounds here (I <= 1e12
photons/min, dwell <= 1e3 min, detector <= 1e4 cm^2, area side >= 10 m over <= 64 cells, so
d >= 7.8 cm) it stays below 1.3e16, inside what numpy's Poisson sampler takes (~9e18) and far
inside float32 (the readings maps). The resource model (:mod:`workers.mdrl.resources`) then
bounds memory and compute, which depend on several fields at once.
"""

from __future__ import annotations

import dataclasses
import json
import re
from dataclasses import dataclass
from typing import Any

from workers.mdrl.env import LayoutError, check_layout_fit
from workers.mdrl.observations import KINDS, ObservationSpec, check_joint_actions
from workers.mdrl.ppo import PPOConfig
from workers.mdrl.presets import FAST_PPO, PRESETS, get_preset
from workers.mdrl.spec import MAX_SPARSE_BONUS, EnvSpec, IntensitySpec
from workers.mdrl.specfields import (
    Bool,
    Choice,
    Int,
    Nullable,
    Pair,
    Real,
    SpecError,
    check_object,
    join,
    object_schema,
)

__all__ = [
    "MAX_SPEC_BYTES",
    "TRAINING_SPEC_FORMAT",
    "AlgorithmSpec",
    "BudgetSpec",
    "SelectionSpec",
    "SpecError",
    "TrainingSpec",
    "parse_env",
    "trainingspec_json_schema",
]

TRAINING_SPEC_FORMAT = "drlaas-task/1"
"""Value of the document's ``format`` field."""
MAX_SPEC_BYTES = 64 * 1024
"""The one size limit of a spec document (gateway body, content-store fetch, worker parse)."""
MAX_GRID = 64
MAX_AGENTS = 16
MAX_EXPERTS = 8
MAX_STEPS = 1_000_000_000
"""Env-step budget cap (the resource model bounds the compute of a spec further)."""
MAX_MINUTES = 7 * 24 * 60
"""Wall-clock budget cap: one week."""
INTENSITY_BOUNDS = (1e3, 1e12)
"""Source intensity in photons/min (the thesis uses 1e9; see the module docstring)."""

_INTENSITY = Real(*INTENSITY_BOUNDS, doc="photons/min")
_GRID = Int(2, MAX_GRID, doc="cells")
_WALLS = Int(0, MAX_GRID)

ENV_RULES: dict[str, Any] = {
    "rows": _GRID,
    "cols": _GRID,
    "area_m": Pair(Real(10.0, 1e6), ordered=False, doc="[height, width] of the area, metres"),
    "agents": Int(1, MAX_AGENTS),
    "intensity": None,  # set below: a number or {kind, values}
    "moves": Choice((4, 8), doc="4 moves or 8 directions, plus idle"),
    "walls": Pair(_WALLS, doc="[min, max] walls per episode; max <= max(rows, cols)"),
    "wall_length": Nullable(Pair(Int(1, MAX_GRID), doc="[min, max] cells")),
    "reward": Choice(("shaped", "sparse")),
    "sparse_bonus": Real(0.0, MAX_SPARSE_BONUS),
    "max_steps": Int(1, 10_000, doc="steps per episode"),
    "idle_limit": Int(1, 10_000),
    "detector_area_cm2": Real(1e-3, 1e4),
    "dwell_min": Real(1e-3, 1e3),
    "wall_mu_per_cm": Real(0.0, 100.0),
    "wall_thickness_cm": Real(0.0, 1e3),
    "readings": Choice(("poisson", "expected")),
}
OBSERVATION_RULES: dict[str, Any] = {
    "kind": Choice(KINDS, doc="odmtl | dmtl | cmtl (thesis 3.6, 3.5, 3.4)"),
    "window": Int(3, 31, odd=True, doc="odd; odmtl needs window < min(rows, cols)"),
    "walls": Nullable(Bool(doc="wall maps; null = iff the env can have walls")),
    "critic": Choice(("reduced", "full")),
    "readings": Choice(("last", "mean"), doc="last reading per cell (thesis) or the mean"),
    "scale": Choice(("max", "fixed"), doc="readings / episode max (thesis) or log physical"),
    "belief": Bool(doc="add the team's posterior map of the target cell"),
    "route": Bool(doc="odmtl with belief: add the walking-distance maps to the posterior"),
    "others": Nullable(Bool(doc="others map; null = iff more than one agent")),
    "walls_embedding": None,  # set below: a walls CAE (Ch. 4) by model CID, or null
    "walls_embedding_size": Int(1, 1024, doc="d of the walls CAE (Ch. 4: 128)"),
}
PPO_RULES: dict[str, Any] = {
    "learning_rate": Real(1e-7, 1.0),
    "clip_coef": Real(1e-3, 1.0),
    "ent_coef": Real(0.0, 1.0),
    "gamma": Real(0.0, 1.0),
    "gae_lambda": Real(0.0, 1.0),
    "horizon": Int(1, 1_000_000, doc="env steps per update"),
    "update_epochs": Int(1, 100),
    "vf_coef": Real(0.0, 100.0),
    "num_minibatches": Int(1, 1024),
    "max_grad_norm": Real(1e-3, 1e3),
    "num_envs": Int(1, 4096),
    "anneal_lr": Bool(),
    "norm_adv": Bool(),
    "clip_vloss": Bool(),
    "target_kl": Nullable(Real(1e-6, 10.0)),
    "adam_eps": Real(1e-12, 1.0),
    "reward_scale": Real(1e-6, 1e6),
}
BUDGET_RULES: dict[str, Any] = {
    "steps": Int(1, MAX_STEPS, doc="env steps to train (training stops at exactly this many)"),
    "minutes": Real(0.1, MAX_MINUTES, doc="wall-clock cap in minutes"),
}
SELECTION_RULES: dict[str, Any] = {
    "keep_best": Nullable(Choice(("time", "cost"), doc="deliver the policy with the shortest "
                                 "mean episode (time) or the lowest moving cost (cost) over the "
                                 "job's greedy evaluations; null = the final policy")),
    "eval_every": Int(1, 10_000, doc="updates between those evaluations (default 5)"),
}
"""``selection``: which policy of the run the worker delivers (``RunConfig.keep_best``)."""
JOB_EVAL_EPISODES = 100
"""Greedy evaluation episodes of a platform job (the card's metrics; with ``selection.keep_best``
every ``eval_every`` updates, which the resource model charges for)."""
DEMONSTRATION_RULES: dict[str, Any] = {
    "rate": Nullable(Real(0.0, 1.0, doc="R_E: share of expert-guided episodes; null = 0.2 for "
                          "one expert (Table 4.1), 0.1 for several (Table 5.3)")),
    "rate_end": Nullable(Real(0.0, 1.0, doc="R_E at the end of budget.steps, reached linearly "
                              "from rate (ours); null = R_E fixed, as Alg. 5.1")),
    "threshold": Real(0.0, 0.99, doc="l: follow an expert's action only if its probability "
                      "under the learner's policy exceeds l (Tables 4.1, 5.3: 0.05)"),
    "credit": Bool(doc="expert credit (ours): experts whose guided episodes are no shorter "
                   "than the agents' own fade out (medc.py); default false, as Alg. 5.1"),
}
"""``algorithm.demonstration``: how the ``experts`` guide training (DC / MEDC, medc.py)."""
EXPERT_QOS = Real(0.0, 1e6, doc="QoS weight; the expert is picked with R_S = QoS / sum QoS "
                  "(Table 5.3); default 1")
SPEC_CID_PATTERN = r"Qm[1-9A-HJ-NP-Za-km-z]{44}|b[a-z2-7]{50,120}"
"""A model CID as a spec writes it: v0 or base32 v1 (the store checks it decodes)."""
# an expert is a model CID or a relative path without '.'-segments
EXPERT_PATTERN = (
    rf"^({SPEC_CID_PATTERN}"
    r"|[A-Za-z0-9_-][A-Za-z0-9_.-]{0,63}(/[A-Za-z0-9_-][A-Za-z0-9_.-]{0,63}){0,7})$"
)


class _Intensity:
    """``1e9`` (fixed) or ``{"kind": "fixed"|"choice"|"uniform", "values": [...]}``."""

    _KIND = Choice(("fixed", "choice", "uniform"))
    _COUNTS = {"fixed": (1, 1), "choice": (1, 16), "uniform": (2, 2)}

    def check(self, v: Any, field: str) -> IntensitySpec:
        if not isinstance(v, dict):
            return IntensitySpec.fixed(_INTENSITY.check(v, field))
        for key in v:
            if key not in ("kind", "values"):
                raise SpecError(f"{field}.{key}", "unknown field (known: kind, values)")
        kind = self._KIND.check(v.get("kind", "fixed"), f"{field}.kind")
        values = v.get("values")
        lo, hi = self._COUNTS[kind]
        if not isinstance(values, list) or not lo <= len(values) <= hi:
            raise SpecError(f"{field}.values", f"a {kind} intensity needs {lo}-{hi} values")
        vals = tuple(_INTENSITY.check(x, f"{field}.values[{i}]") for i, x in enumerate(values))
        if kind == "uniform" and vals[0] > vals[1]:
            raise SpecError(f"{field}.values", f"uniform needs [low, high], got {list(vals)}")
        return IntensitySpec(kind, vals)

    def schema(self) -> dict[str, Any]:
        def variant(kind: str) -> dict[str, Any]:
            lo, hi = self._COUNTS[kind]
            values = {"type": "array", "items": _INTENSITY.schema(), "minItems": lo, "maxItems": hi}
            return {
                "type": "object",
                "properties": {"kind": {"const": kind}, "values": values},
                "required": ["kind", "values"],
                "additionalProperties": False,
            }

        return {
            "description": "photons/min: one value, a set to draw from, or a [low, high] range",
            "anyOf": [_INTENSITY.schema()] + [variant(k) for k in self._COUNTS],
        }


ENV_RULES["intensity"] = _Intensity()


@dataclass(frozen=True)
class AlgorithmSpec:
    """PPO settings: a named preset's (or the default fast settings) plus field overrides."""

    preset: str | None = None
    ppo: dict[str, Any] = dataclasses.field(default_factory=dict)
    demonstration: dict[str, Any] = dataclasses.field(default_factory=dict)
    """DC / MEDC settings (``DEMONSTRATION_RULES``); they apply when the spec names experts."""

    def config(self, steps: int | None) -> PPOConfig:
        """The PPOConfig to train with (a small step budget gets a small default batch)."""
        base = get_preset(self.preset).ppo.to_dict() if self.preset else default_ppo(steps)
        return PPOConfig.from_dict({**base, **self.ppo})

    def to_dict(self) -> dict[str, Any]:
        doc = {"preset": self.preset, "ppo": dict(self.ppo)}
        if self.demonstration:
            doc["demonstration"] = dict(self.demonstration)
        return doc


@dataclass(frozen=True)
class BudgetSpec:
    steps: int | None = None
    minutes: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in dataclasses.asdict(self).items() if v is not None}


@dataclass(frozen=True)
class SelectionSpec:
    """Which policy of the run is the outcome: the final one, or (``keep_best``) the best of
    greedy evaluations every ``eval_every`` updates (``RunConfig.keep_best``); the model card
    says when it was chosen (``training.selected``)."""

    keep_best: str | None = None
    eval_every: int = 5

    def to_dict(self) -> dict[str, Any]:
        return {"keep_best": self.keep_best, "eval_every": self.eval_every}


def default_ppo(steps: int | None) -> dict[str, Any]:
    """FAST_PPO, with an update no larger than a quarter of a small step budget so a tiny
    budget still gives several updates (and so checkpoints and progress points)."""
    ppo = dict(FAST_PPO)
    if steps is not None and steps < 4 * ppo["horizon"]:
        envs = 16 if steps < 4096 else 32
        ppo.update(num_envs=envs, horizon=max(envs, steps // 4 // envs * envs), update_epochs=2)
    return ppo


@dataclass(frozen=True)
class TrainingSpec:
    """What a worker trains and for how long (see the module docstring)."""

    env: EnvSpec
    observation: ObservationSpec
    algorithm: AlgorithmSpec
    budget: BudgetSpec
    seed: int = 0
    experts: tuple[str, ...] = ()
    expert_qos: tuple[float, ...] = ()
    """QoS weight per expert (R_S = QoS_i / sum QoS, Table 5.3); empty = equal weights."""
    selection: SelectionSpec = SelectionSpec()
    outcome_key: str | None = None
    """The requester's secp256k1 public key (``0x`` + 128 hex digits): the worker seals the
    outcome's weights to it (backend/store/sealed.py); None = the outcome is public."""

    @property
    def ppo(self) -> PPOConfig:
        return self.algorithm.config(self.budget.steps)

    @property
    def steps(self) -> int | None:
        return self.budget.steps

    def demonstration(self) -> Any:
        """The run's ``medc.DemonstrationConfig``, or None when the spec names no experts.
        An expert of QoS weight 0 is left out: the roulette wheel (R_S = QoS / sum QoS) never
        picks it, so a worker does not fetch it and the model's card does not list it as used."""
        if not self.experts:
            return None
        from workers.mdrl.medc import DemonstrationConfig

        experts, qos = self.experts, self.expert_qos
        if qos:  # _check_experts: not all 0
            experts = tuple(m for m, q in zip(experts, qos, strict=True) if q > 0)
            qos = tuple(q for q in qos if q > 0)
        d = self.algorithm.demonstration
        return DemonstrationConfig(experts, qos, d.get("rate"),
                                   d.get("threshold", DemonstrationConfig.threshold),
                                   d.get("credit", False), d.get("rate_end"))

    @property
    def minutes(self) -> float | None:
        return self.budget.minutes

    def run_config(self, **changes: Any) -> Any:
        """The ``train.RunConfig`` a worker trains this spec with (``workers/daemon/job.py``,
        ``drlaas train --task``): its seed and budget, JOB_EVAL_EPISODES greedy evaluation
        episodes, and the evaluations ``selection.keep_best`` asks for; ``changes`` on top."""
        from workers.mdrl.train import RunConfig

        keep = self.selection.keep_best
        return RunConfig.from_dict({
            "seed": self.seed, "total_steps": self.steps, "minutes": self.minutes,
            "eval_every": self.selection.eval_every if keep else 0, "keep_best": keep,
            "eval_episodes": JOB_EVAL_EPISODES, **changes,
        })

    # -- parsing ---------------------------------------------------------------------------
    @classmethod
    def from_json(cls, raw: bytes | str) -> TrainingSpec:
        """Parse a document's bytes; refuses more than :data:`MAX_SPEC_BYTES` before parsing."""
        if len(raw) > MAX_SPEC_BYTES:
            raise SpecError("spec", f"{len(raw)} bytes > limit of {MAX_SPEC_BYTES}")
        try:
            doc = json.loads(raw)
        except (ValueError, RecursionError) as exc:
            raise SpecError("spec", f"not JSON ({exc})") from None
        return cls.from_dict(doc)

    @classmethod
    def from_dict(cls, doc: Any) -> TrainingSpec:
        """Check ``doc`` field by field, then the cross-field rules; SpecError names the field."""
        if not isinstance(doc, dict):
            raise SpecError("spec", "expected a JSON object")
        top = {"format", "env", "observation", "algorithm", "budget", "seed", "experts",
               "selection", "outcome_key"}
        for key in doc:
            if key not in top:
                raise SpecError(key, f"unknown field (known: {sorted(top)})")
        if doc.get("format", TRAINING_SPEC_FORMAT) != TRAINING_SPEC_FORMAT:
            raise SpecError("format", f"expected {TRAINING_SPEC_FORMAT!r}")
        for key in ("env", "budget"):
            if key not in doc:
                raise SpecError(key, "required")
        obs = check_object(doc.get("observation", {}), OBSERVATION_RULES, "observation")
        algo = check_object(doc.get("algorithm", {}), _ALGORITHM_RULES, "algorithm")
        budget = check_object(doc["budget"], BUDGET_RULES, "budget")
        if not budget:
            raise SpecError("budget", "give steps and/or minutes")
        seed = _SEED.check(doc.get("seed", 0), "seed")
        selection = check_object(doc.get("selection", {}), SELECTION_RULES, "selection")
        if "eval_every" in selection and selection.get("keep_best") is None:
            raise SpecError("selection.eval_every", "applies only with selection.keep_best")
        experts, qos = _check_experts(doc.get("experts", []))
        demonstration = algo.get("demonstration") or {}
        if demonstration and not experts:
            raise SpecError("algorithm.demonstration", "applies only when experts are named")
        if demonstration.get("rate_end") is not None and budget.get("steps") is None:
            raise SpecError("algorithm.demonstration.rate_end",
                            "an expert rate schedule needs budget.steps")
        if (algo.get("ppo") or {}).get("anneal_lr") and budget.get("steps") is None:
            raise SpecError("algorithm.ppo.anneal_lr",
                            "a learning-rate schedule needs budget.steps (it anneals over them)")
        if "walls_embedding_size" in obs and obs.get("walls_embedding") is None:
            raise SpecError("observation.walls_embedding_size", "applies only with "
                            "observation.walls_embedding (it is that walls CAE's d)")
        if obs.get("route") and not (obs.get("belief") and obs.get("kind", "odmtl") == "odmtl"):
            raise SpecError("observation.route", "needs observation.kind = odmtl and "
                            "observation.belief = true (the walking distance to the belief)")
        try:
            observation = ObservationSpec(**obs)
        except ValueError as exc:  # a rule between fields that the checks above do not name
            raise SpecError("observation", str(exc)) from None
        spec = cls(
            env=parse_env(doc["env"]),
            observation=observation,
            algorithm=AlgorithmSpec(algo.get("preset"), algo.get("ppo") or {}, demonstration),
            budget=BudgetSpec(budget.get("steps"), budget.get("minutes")),
            seed=seed,
            experts=experts,
            expert_qos=qos,
            selection=SelectionSpec(**selection),
            outcome_key=_OUTCOME_KEY.check(doc["outcome_key"], "outcome_key")
            if doc.get("outcome_key") is not None
            else None,
        )
        spec._check_cross_fields()
        return spec

    def _check_cross_fields(self) -> None:
        e, o = self.env, self.observation
        if o.kind == "odmtl" and not o.window < min(e.rows, e.cols):
            raise SpecError(
                "observation.window",
                f"odmtl window must be < min(rows, cols) = {min(e.rows, e.cols)}, got {o.window}",
            )
        if o.kind == "cmtl":  # agents <= 16 pass their own bound; A**N is the trainer's
            try:
                check_joint_actions(e.num_actions, e.agents)
            except ValueError as exc:
                raise SpecError("observation.kind", str(exc)) from None
        try:
            self.ppo  # noqa: B018 - PPOConfig checks its merged fields
        except ValueError as exc:
            raise SpecError("algorithm.ppo", str(exc)) from None

    # -- output ----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The JSON document; ``TrainingSpec.from_dict(spec.to_dict()) == spec``."""
        return {
            "format": TRAINING_SPEC_FORMAT,
            "env": self.env.to_dict(),
            "observation": self.observation.to_dict(),
            "algorithm": self.algorithm.to_dict(),
            "budget": self.budget.to_dict(),
            "seed": self.seed,
            "experts": (
                [{"model": m, "qos": q} for m, q in zip(self.experts, self.expert_qos, strict=True)]
                if self.expert_qos
                else list(self.experts)
            ),
        } | ({"selection": self.selection.to_dict()} if self.selection.keep_best else {}) | (
            {"outcome_key": self.outcome_key} if self.outcome_key else {}
        )


def parse_env(doc: Any, field: str = "env") -> EnvSpec:
    """An EnvSpec document checked against the task-spec bounds (also used for model cards);
    :class:`SpecError` names the field under ``field``."""
    return _env(check_object(doc, ENV_RULES, field), field)


def _env(fields: dict[str, Any], field: str = "env") -> EnvSpec:
    """EnvSpec from checked fields; its own cross-field problems named by field."""
    rows, cols = fields.get("rows", EnvSpec.rows), fields.get("cols", EnvSpec.cols)
    agents = fields.get("agents", EnvSpec.agents)
    if agents + 1 > rows * cols:
        raise SpecError(
            join(field, "agents"), f"{agents} agents and a target do not fit on {rows}x{cols}"
        )
    walls = fields.get("walls", (0, 0))
    if walls[1] > max(rows, cols):
        raise SpecError(join(field, "walls"), f"at most {max(rows, cols)} walls, got {list(walls)}")
    if walls[1] > 0 and min(rows, cols) < 4:
        raise SpecError(join(field, "walls"), "walls need a grid of at least 4x4")
    length = fields.get("wall_length")
    if walls[1] > 0 and length is not None and length[0] > max(rows, cols) - 2:
        raise SpecError(  # it was drawn shorter than asked, and the card kept the ask
            join(field, "wall_length"),
            f"walls are at most {max(rows, cols) - 2} cells long on {rows}x{cols} (they stop "
            f"short of the far side), got at least {length[0]}",
        )
    try:
        spec = EnvSpec(**fields)
    except ValueError as exc:  # a rule of EnvSpec not mirrored above
        raise SpecError(field or "env", str(exc)) from None
    try:  # what every worker's env would refuse after the task was paid for (cached per spec)
        check_layout_fit(spec)
    except LayoutError as exc:
        raise SpecError(join(field, "walls"), str(exc)) from None
    return spec


class _PresetName:
    def check(self, v: Any, field: str) -> str | None:
        if v is not None and not isinstance(v, str):  # a dict or list is not hashable
            raise SpecError(field, f"expected a preset name or null, got {type(v).__name__}")
        if v is not None and v not in PRESETS:
            raise SpecError(field, f"unknown preset {v!r}; known: {', '.join(sorted(PRESETS))}")
        return v

    def schema(self) -> dict[str, Any]:
        return {"anyOf": [{"enum": sorted(PRESETS)}, {"type": "null"}]}


class _PPOObject:
    def check(self, v: Any, field: str) -> dict[str, Any]:
        return check_object(v, PPO_RULES, field)

    def schema(self) -> dict[str, Any]:
        return object_schema(PPO_RULES, "PPOConfig overrides (workers.mdrl.ppo)")


class _Demonstration:
    def check(self, v: Any, field: str) -> dict[str, Any]:
        return check_object(v, DEMONSTRATION_RULES, field)

    def schema(self) -> dict[str, Any]:
        return object_schema(DEMONSTRATION_RULES, "DC / MEDC settings (medc.py)")


_PRESET = _PresetName()
_PPO_OBJECT = _PPOObject()
_ALGORITHM_RULES = {"preset": _PRESET, "ppo": _PPO_OBJECT, "demonstration": _Demonstration()}
_SEED = Int(0, 2**32 - 1)


def _check_experts(v: Any) -> tuple[tuple[str, ...], tuple[float, ...]]:
    """-> (model references, QoS weights); the weights are () when every item is a plain
    reference (equal weights), else one per expert (1 for plain references)."""
    if not isinstance(v, list) or len(v) > MAX_EXPERTS:
        raise SpecError("experts", f"expected a list of at most {MAX_EXPERTS} model CIDs/paths")
    models, qos = [], []
    for i, x in enumerate(v):
        field = f"experts[{i}]"
        if isinstance(x, dict):
            item = check_object(x, {"model": _EXPERT_REF, "qos": EXPERT_QOS}, field)
            if "model" not in item:
                raise SpecError(join(field, "model"), "required")
            models.append(item["model"])
            qos.append(item.get("qos", 1.0))
        else:
            models.append(_EXPERT_REF.check(x, field))
            qos.append(None)
    if len(set(models)) != len(models):
        raise SpecError("experts", "duplicate expert")
    if all(q is None for q in qos):
        return tuple(models), ()
    weights = tuple(1.0 if q is None else q for q in qos)
    if sum(weights) <= 0:
        raise SpecError("experts", "the QoS weights are all 0: no expert could be picked")
    return tuple(models), weights


class _ExpertRef:
    def check(self, v: Any, field: str) -> str:
        if not isinstance(v, str) or not re.fullmatch(EXPERT_PATTERN, v):
            raise SpecError(field, f"expected a model CID or relative path, got {v!r}")
        return v

    def schema(self) -> dict[str, Any]:
        return {"type": "string", "pattern": EXPERT_PATTERN, "maxLength": 600}


_EXPERT_REF = _ExpertRef()
OBSERVATION_RULES["walls_embedding"] = Nullable(_EXPERT_REF)
ROUTE_NEEDS_ODMTL_BELIEF = {
    "if": {"properties": {"route": {"const": True}}, "required": ["route"]},
    "then": {"properties": {"belief": {"const": True}, "kind": {"const": "odmtl"}},
             "required": ["belief"]},
}
"""observation.route = true needs belief = true and kind odmtl (the default): the rule of
``from_dict`` as JSON Schema, so a client sees it before it sends the spec."""

OUTCOME_KEY_PATTERN = "^0x[0-9a-fA-F]{128}$"


class _OutcomeKey:
    """An uncompressed secp256k1 public key (x || y), checked to be on the curve."""

    def check(self, v: Any, field: str) -> str:
        if not isinstance(v, str) or not re.fullmatch(OUTCOME_KEY_PATTERN, v):
            raise SpecError(field, "expected 0x + 128 hex digits (a secp256k1 public key)")
        x, y = int(v[2:66], 16), int(v[66:], 16)
        if x >= _SECP256K1_P or y >= _SECP256K1_P or (y * y - x**3 - 7) % _SECP256K1_P:
            raise SpecError(field, "not a point of secp256k1")
        return v.lower()

    def schema(self) -> dict[str, Any]:
        return {
            "type": "string",
            "pattern": OUTCOME_KEY_PATTERN,
            "description": "the requester's secp256k1 public key: the worker seals the "
            "outcome's weights to it (its address must be the task's requester)",
        }


_SECP256K1_P = 2**256 - 2**32 - 977
_OUTCOME_KEY = _OutcomeKey()


def trainingspec_json_schema() -> dict[str, Any]:
    """JSON Schema (2020-12 / OpenAPI 3.1) of a spec document, from the same rules as the parser.

    Cross-field rules (window < min(rows, cols), walls <= max(rows, cols), agents fit the grid,
    the resource limits) cannot be written as JSON Schema; the parser reports them by field."""
    budget = object_schema(BUDGET_RULES, "steps and/or minutes", minProperties=1)
    weighted = object_schema({"model": _EXPERT_REF, "qos": EXPERT_QOS}, "an expert and its "
                             "QoS weight", required=["model"])
    experts = {
        "type": "array",
        "items": {"anyOf": [_EXPERT_REF.schema(), weighted]},
        "maxItems": MAX_EXPERTS,
        "uniqueItems": True,
        "description": "expert models guiding training (DC / MEDC): CIDs or relative paths, "
        "or {model, qos} objects; may be empty",
    }
    algorithm = object_schema(
        _ALGORITHM_RULES, "PPO: a preset's settings plus overrides; DC / MEDC settings"
    )
    return {
        "type": "object",
        "title": "TrainingSpec",
        "properties": {
            "format": {"const": TRAINING_SPEC_FORMAT},
            "env": object_schema(ENV_RULES, "EnvSpec fields (workers.mdrl.spec)"),
            "observation": object_schema(OBSERVATION_RULES, "ObservationSpec fields",
                                         **ROUTE_NEEDS_ODMTL_BELIEF),
            "algorithm": algorithm,
            "budget": budget,
            "seed": _SEED.schema(),
            "experts": experts,
            "selection": object_schema(SELECTION_RULES, "which policy of the run the worker "
                                       "delivers: the final one (default) or the best evaluated",
                                       dependentRequired={"eval_every": ["keep_best"]}),
            "outcome_key": _OUTCOME_KEY.schema(),
        },
        "required": ["env", "budget"],
        "additionalProperties": False,
    }
