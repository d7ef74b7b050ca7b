"""What the model page reads from a model card (``model.json`` of the bundle).

A card comes from the content store and was written by anyone who shared a bundle: it is
untrusted. :meth:`CardView.from_card` parses each section on its own against bounded schemas
and drops what does not validate (a curve point, a reading model, a section), so a hostile or
broken card leaves a page with less on it, never a 500. The card formats are those of
``workers.mdrl.modelio`` (``metrics``, ``training``), ``workers.mdrl.curve`` (``curve``) and
``workers.mdrl.zoo`` (``zoo.heldout``).
"""

from __future__ import annotations

import logging
import math
import re
from functools import partial
from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field, ValidationError, field_validator, model_validator

from .common import CID_PATTERN, VisibleText

log = logging.getLogger(__name__)

MAX_CARD_CURVE_POINTS = 1000
"""A card's curve longer than this is dropped (workers write at most 200: curve.py)."""
MAX_EXPERTS = 16
MAX_BASELINES = 8
READING_MODELS = ("poisson", "expected")
"""The held-out reading models of a zoo card (workers.mdrl.zoo.READING_MODELS)."""

Steps = Annotated[float, Field(ge=0.0, le=1e6, allow_inf_nan=False)]
Cost = Annotated[float, Field(ge=0.0, le=1e12, allow_inf_nan=False)]
Rate = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]


class CurvePointPublic(BaseModel):
    """One point of a model's training curve (env steps so far and the update's episodes)."""

    step: int = Field(ge=0, le=10**12, description="environment steps so far")
    wall_s: float | None = Field(
        default=None, ge=0.0, le=1e9, allow_inf_nan=False, description="training seconds so far"
    )
    success: Rate | None = Field(default=None, description="success rate")
    time: Steps | None = Field(default=None, description="mean episode length (time steps)")
    cost: Cost | None = Field(default=None, description="mean moving cost per episode")


class BaselineFiguresPublic(BaseModel):
    """A baseline search policy (workers/mdrl/baselines.py) on the same held-out episodes."""

    name: str = Field(pattern=r"^[a-z][a-z0-9_-]{0,31}$", description="bayes, uniform, random")
    success: Rate
    time: Steps | None = None
    time_ci: tuple[Steps, Steps] | None = None
    cost: Cost | None = None
    cost_ci: tuple[Cost, Cost] | None = None
    time_vs_oracle: float | None = None


class HeldoutFiguresPublic(BaseModel):
    """Greedy figures on the card's held-out episodes under one reading model, next to the
    oracle (which knows the target: a lower bound on search time) and the baselines."""

    reading_model: Literal["poisson", "expected"]
    baselines: list[BaselineFiguresPublic] = Field(default_factory=list)
    success: Rate
    time: Steps | None = None
    time_ci: tuple[Steps, Steps] | None = Field(default=None, description="95% interval")
    cost: Cost | None = None
    cost_ci: tuple[Cost, Cost] | None = Field(default=None, description="95% interval")
    oracle_time: Steps | None = None
    time_vs_oracle: float | None = Field(
        default=None, description="time / oracle_time (computed by the gateway)"
    )


class HeldoutPublic(BaseModel):
    episodes: int = Field(ge=1, le=10**9)
    seed: int | None = Field(default=None, ge=0, le=2**63 - 1)
    readings: list[HeldoutFiguresPublic]


class FinalEvalPublic(BaseModel):
    """The trainer's last greedy evaluation (``metrics.eval_*``: the run's own eval episodes,
    not held out)."""

    success: Rate | None = None
    time: Steps | None = None
    cost: Cost | None = None


class TrainedPublic(BaseModel):
    env_steps: int | None = Field(default=None, ge=0, le=10**12)
    updates: int | None = Field(default=None, ge=0, le=10**9)
    wall_time_s: float | None = Field(default=None, ge=0.0, le=1e9, allow_inf_nan=False)
    selected_by: Literal["time", "cost"] | None = Field(
        default=None,
        description="the run's best evaluated policy by this figure (RunConfig.keep_best), "
        "not its last one; env_steps and updates are then when it was chosen",
    )


class CardExpertRef(BaseModel):
    ref: VisibleText = Field(min_length=1, max_length=200)


class ExpertTrialPublic(BaseModel):
    """The expert followed by the team on the run's task after the run, next to the oracle on
    the same episodes (``training.experts.review``, workers/mdrl/review.py): the worker's
    evidence for the requester's review, and the review it suggests."""

    episodes: int = Field(ge=1, le=10**6)
    success: Rate
    time: Steps
    time_vs_oracle: float | None = Field(default=None, ge=0.0, le=1e6, allow_inf_nan=False)
    suggested_review: int = Field(ge=0, le=5, description="round(5 x success x oracle/time)")


class ExpertUsagePublic(BaseModel):
    """How a DC / MEDC run used one expert (``training.experts.experts[i]``, medc.py): the
    card's word, shown next to the expert."""

    episodes: int = Field(ge=0, le=10**12, description="episodes this expert guided")
    decisions: int = Field(default=0, ge=0, le=10**15, description="agent decisions it ranked")
    followed: int = Field(
        default=0, ge=0, le=10**15, description="of those, where the agent took its action"
    )
    agreed: int | None = Field(
        default=None, ge=0, le=10**15,
        description="of those, where the agent took the expert's own first choice",
    )
    selection_probability: float | None = Field(
        default=None, ge=0.0, le=1.0, allow_inf_nan=False, description="R_S = QoS / sum QoS"
    )
    trial: ExpertTrialPublic | None = Field(
        default=None, description="the expert on the task after the run; null: not measured"
    )

    @model_validator(mode="after")
    def _followed_within_decisions(self) -> ExpertUsagePublic:
        if self.followed > self.decisions:
            raise ValueError("followed > decisions")
        if self.agreed is not None and self.agreed > self.followed:
            raise ValueError("agreed > followed")
        return self


class CardView(BaseModel):
    """The validated parts of a card the model page shows."""

    name: VisibleText | None = Field(default=None, max_length=100)
    kind: str | None = Field(default=None, max_length=16, description="ODMTL, DMTL or CMTL")
    curve: list[CurvePointPublic] = Field(default_factory=list)
    curve_updates: int | None = Field(default=None, ge=0, le=10**9)
    heldout: HeldoutPublic | None = None
    final_eval: FinalEvalPublic | None = None
    trained: TrainedPublic | None = None
    expert_refs: list[str] = Field(default_factory=list)
    expert_usage: dict[str, ExpertUsagePublic] = Field(default_factory=dict)
    """By ref: what the card says each expert did in the run (refs without a valid record
    are left out)."""

    @field_validator("kind")
    @classmethod
    def _kind(cls, v: str | None) -> str | None:
        return v if v in (None, "ODMTL", "DMTL", "CMTL") else None

    @classmethod
    def from_card(cls, card: Any) -> CardView:
        """Parse what validates of ``card`` (any JSON value); never raises."""
        if not isinstance(card, dict):
            return cls()
        zoo = _obj(card.get("zoo"))
        training = _obj(card.get("training"))
        curve_doc = _obj(card.get("curve"))
        curve = _points(curve_doc.get("points"))
        return cls(
            name=_section(lambda: CardView(name=zoo.get("name")).name),
            kind=_section(lambda: CardView(kind=card.get("model")).kind),
            curve=curve,
            curve_updates=_section(
                lambda: CardView(curve_updates=curve_doc.get("updates")).curve_updates
            )
            if curve
            else None,
            heldout=_heldout(zoo.get("heldout")),
            final_eval=_final_eval(card.get("metrics")),
            trained=_section(lambda: _trained(training)),
            expert_refs=_expert_refs(training.get("experts")),
            expert_usage=_expert_usage(training.get("experts")),
        )


def _trained(training: dict[str, Any]) -> TrainedPublic:
    by = _obj(training.get("selected")).get("by")
    fields = {k: training.get(k) for k in ("env_steps", "updates", "wall_time_s")}
    return TrainedPublic.model_validate(
        {**fields, "selected_by": by if by in ("time", "cost") else None}
    )


def _obj(v: Any) -> dict[str, Any]:
    return v if isinstance(v, dict) else {}


def _section(build: Any) -> Any:
    """A card section, or None when the owner's card gets it wrong. Logged at DEBUG only: a
    card is untrusted input that the model page shows without the section, not a gateway
    fault, and a card of many bad curve points would log a line per point per view."""
    try:
        return build()
    except (ValidationError, TypeError, ValueError) as exc:
        log.debug("model card section dropped: %s", str(exc)[:200])
        return None


def _points(raw: Any) -> list[CurvePointPublic]:
    if not isinstance(raw, list) or len(raw) > MAX_CARD_CURVE_POINTS:
        return []
    out = [p for p in (_section(lambda p=p: CurvePointPublic.model_validate(p)) for p in raw) if p]
    return sorted(out, key=lambda p: p.step)


def _heldout(raw: Any) -> HeldoutPublic | None:
    held = _obj(raw)
    readings = []
    for name in READING_MODELS:
        figures = _obj(held.get(name))
        fig = _section(
            lambda f=figures, n=name: HeldoutFiguresPublic.model_validate(
                {
                    **{k: f.get(k) for k in HeldoutFiguresPublic.model_fields},
                    "reading_model": n,
                    "baselines": [],
                    "time_vs_oracle": None,
                }
            )
        )
        if fig is None:
            continue
        fig.baselines = _baselines(figures.get("baselines"))
        for f in (fig, *fig.baselines):
            if f.time is not None and fig.oracle_time:
                f.time_vs_oracle = f.time / fig.oracle_time
        readings.append(fig)
    if not readings:
        return None
    return _section(
        lambda: HeldoutPublic(
            episodes=held.get("episodes"), seed=held.get("seed"), readings=readings
        )
    )


def _baselines(raw: Any) -> list[BaselineFiguresPublic]:
    """``{name: figures}`` of one reading model (workers.mdrl.zoo.baselines); invalid ones are
    left out."""
    if not isinstance(raw, dict):
        return []
    keys = [k for k in BaselineFiguresPublic.model_fields if k not in ("name", "time_vs_oracle")]
    out = []
    for name, f in list(raw.items())[:MAX_BASELINES]:
        figures = _obj(f)
        fig = _section(
            partial(
                BaselineFiguresPublic.model_validate,
                {"name": name} | {k: figures.get(k) for k in keys},
            )
        )
        if fig is not None:
            out.append(fig)
    return out


def _final_eval(raw: Any) -> FinalEvalPublic | None:
    metrics = _obj(raw)
    values = {k: metrics.get(f"eval_{k}") for k in ("success", "time", "cost")}
    values = {k: v for k, v in values.items() if not (isinstance(v, float) and math.isnan(v))}
    if all(v is None for v in values.values()):
        return None
    return _section(lambda: FinalEvalPublic.model_validate(values))


def _expert_refs(raw: Any) -> list[str]:
    """``training.experts.experts[*].ref`` of an expert-guided run (workers.mdrl.medc)."""
    experts = _obj(raw).get("experts")
    if not isinstance(experts, list):
        return []
    refs = [_section(lambda e=e: CardExpertRef.model_validate(e).ref) for e in experts]
    return [r for r in refs if r][:MAX_EXPERTS]


def _expert_trials(raw: Any) -> dict[str, ExpertTrialPublic]:
    """``training.experts.review.experts`` by ref (workers/mdrl/review.py); the episodes are
    the review's, one count for all."""
    review = _obj(_obj(raw).get("review"))
    rows = review.get("experts")
    if not isinstance(rows, list):
        return {}
    out: dict[str, ExpertTrialPublic] = {}
    for e in rows[:MAX_EXPERTS]:
        ref = _section(lambda e=e: CardExpertRef.model_validate(e).ref)
        if not ref or ref in out:
            continue
        trial = _section(lambda e=e: ExpertTrialPublic.model_validate(
            {**{k: e.get(k) for k in ExpertTrialPublic.model_fields if k in e},
             "episodes": review.get("episodes")}))
        if trial is not None:
            out[ref] = trial
    return out


def _expert_usage(raw: Any) -> dict[str, ExpertUsagePublic]:
    experts = _obj(raw).get("experts")
    if not isinstance(experts, list):
        return {}
    trials = _expert_trials(raw)
    out: dict[str, ExpertUsagePublic | None] = {}
    for e in experts[:MAX_EXPERTS]:
        if not isinstance(e, dict):
            continue
        ref = _section(lambda e=e: CardExpertRef.model_validate(e).ref)
        if not ref or ref in out:  # a ref's first record decides
            continue
        out[ref] = _section(
            lambda e=e, ref=ref: ExpertUsagePublic.model_validate(
                {**{k: e.get(k) for k in ExpertUsagePublic.model_fields
                    if k in e and k != "trial"},
                 "trial": trials.get(ref)}
            )
        )
    return {ref: usage for ref, usage in out.items() if usage is not None}


def is_cid(text: str) -> bool:
    """Whether ``text`` is a CID in the store's canonical form (common.CID_PATTERN)."""
    return re.fullmatch(CID_PATTERN, text) is not None
