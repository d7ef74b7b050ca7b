from __future__ import annotations

import math
import re
import unicodedata
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    WithJsonSchema,
    computed_field,
    model_validator,
)

from workers.mdrl.review import middle_review
from workers.mdrl.trainingspec import EXPERT_PATTERN, trainingspec_json_schema

from .cards import ExpertTrialPublic
from .common import (
    CID_LENGTH,
    CID_PATTERN,
    JSON_NUMBER_ONLY,
    MAX_ID,
    PLAIN_TEXT_PATTERN,
    WRITE_BODY,
    Address,
    Count,
    Domain,
    EventPublic,
    Flag,
    Fraction,
    ListPublic,
    Review,
    Wei,
    _printable,
    json_number_only,
)

MAX_EXTRA_METRICS = 16
_METRIC = json_number_only("a metric")


def _format_ranges() -> str:
    """The Basic Multilingual Plane's format characters (Unicode category Cf: bidi controls
    such as U+202E, zero-width ones, U+FEFF) as regex class ranges."""
    codes = [c for c in range(0x10000) if unicodedata.category(chr(c)) == "Cf"]
    ranges: list[tuple[int, int]] = []
    for c in codes:
        if ranges and ranges[-1][1] == c - 1:
            ranges[-1] = (ranges[-1][0], c)
        else:
            ranges.append((c, c))
    return "".join(f"\\u{a:04X}" + (f"-\\u{b:04X}" if b > a else "") for a, b in ranges)


METRIC_NAME_PATTERN = PLAIN_TEXT_PATTERN[:-3] + _format_ranges() + "]*$"
"""A metric name: free text's rule (no control characters) and no invisible format character
(a bidi override reorders what follows it in pages and plots)."""
_METRIC_NAME_FORMAT = re.compile("[" + _format_ranges() + "]")


def _models_by_cid(schema: Any) -> Any:
    """The core's spec schema with every model reference (experts, the walls CAE) narrowed
    from "CID or path" to a CID in the store's form: a platform task names its models by the
    CID of their bundle (no paths, no built-ins), which the route checks (``api/experts.py``)
    and the OpenAPI document now states."""
    if isinstance(schema, list):
        return [_models_by_cid(s) for s in schema]
    if not isinstance(schema, dict):
        return schema
    if schema.get("pattern") == EXPERT_PATTERN:
        return {**schema, "pattern": CID_PATTERN, "minLength": CID_LENGTH, "maxLength": CID_LENGTH}
    return {k: _models_by_cid(v) for k, v in schema.items()}


_SPEC = _models_by_cid(trainingspec_json_schema())["properties"]
SPEC_FIELDS = ("env", "observation", "algorithm", "budget", "seed", "experts", "selection",
               "outcome_key")
"""Fields of the body that make the TrainingSpec document (the rest are task parameters)."""


def _spec_field(name: str) -> Any:
    """A spec field: its JSON Schema is the core's (bounds included); the core's parser
    (TrainingSpec.from_dict, in the route) checks it and names a bad field in the 422."""
    return Annotated[Any, WithJsonSchema(_SPEC[name])]


class TaskCreate(BaseModel):
    """A training task (docs/platform.md): the spec fields (``workers.mdrl.trainingspec``) go to
    the content store as one document, its CID on chain; the rest are the TMC's task parameters."""

    model_config = ConfigDict(extra="forbid")

    env: _spec_field("env")  # type: ignore[valid-type]
    observation: _spec_field("observation") = None  # type: ignore[valid-type]
    algorithm: _spec_field("algorithm") = None  # type: ignore[valid-type]
    budget: _spec_field("budget")  # type: ignore[valid-type]
    seed: _spec_field("seed") = None  # type: ignore[valid-type]
    experts: _spec_field("experts") = None  # type: ignore[valid-type]
    selection: _spec_field("selection") = None  # type: ignore[valid-type]
    outcome_key: _spec_field("outcome_key") = None  # type: ignore[valid-type]
    domain: Domain = 0
    num_workers: Count = Field(default=1, ge=1, le=16)
    min_reputation: Fraction = 0.0
    min_rating: Fraction = 0.0
    min_cpu_cores: Count = Field(default=0, ge=0, le=65_535)
    min_ram_gb: Count = Field(default=0, ge=0, le=65_535)
    deadline_s: Count = Field(
        default=86_400,
        ge=60,
        le=2**32 - 1,
        description="task duration (s); the TMC also requires acceptWindow + minWorkTime <= "
        "deadline_s <= maxDuration (consortium settings; 422 tasks_bad_duration otherwise)",
    )
    payment_wei: Wei(96) = Field(default=0, description="reward per worker, escrowed")  # type: ignore[valid-type]
    expert_allocation: Annotated[int, Field(ge=1, le=MAX_ID), JSON_NUMBER_ONLY] | None = Field(
        default=None,
        description="one of the caller's MMC model allocations (POST /models/requests): its "
        "models become the spec's experts with the QoS the MMC gave them (MEDC); instead of "
        "experts",
    )

    def spec_document(self) -> dict[str, Any]:
        """The spec fields the caller gave (unset ones take the TrainingSpec defaults)."""
        return {k: getattr(self, k) for k in SPEC_FIELDS if k in self.model_fields_set}


class TaskCreatedPublic(BaseModel):
    task_id: int
    spec_cid: str
    offered: list[str]
    tx_hashes: list[str]
    allocation_error: str | None = Field(
        default=None,
        description="set when the task was posted (its escrow held) but allocateTask failed: "
        "retry with POST /tasks/{task_id}/allocate, do not post the task again",
    )


class IntensityPublic(BaseModel):
    kind: Literal["fixed", "choice", "uniform"]
    values: list[float] = Field(description="photons per minute")


class TaskEnvPublic(BaseModel):
    """The environment of a task, from its spec (the document behind the on-chain CID)."""

    rows: int
    cols: int
    agents: int
    walls: tuple[int, int] = Field(description="walls per episode, [min, max]")
    moves: int
    intensity: IntensityPublic


class TaskPublic(BaseModel):
    id: int
    requester: str
    domain: int
    status: str
    num_workers: int
    reward_wei: str
    reward_eth: str = Field(description="reward_wei in ETH, an exact decimal string")
    env: TaskEnvPublic | None = Field(
        description="the spec's environment; null when the description is not a readable spec"
    )
    deadline: int
    min_reputation: float
    min_rating: float
    min_cpu_cores: int
    min_ram_gb: int
    description: str
    offered: int


class OfferPublic(BaseModel):
    worker: str
    state: str
    qos: float
    expiry: int


class OutcomePublic(BaseModel):
    worker: str
    cid: str
    review: int | None
    accepted: bool | None
    model_id: int | None = Field(
        default=None, description="the model listed with this CID (MMC) if its worker shared it"
    )


class ProgressCreate(BaseModel):
    """A training-curve point; extra numeric metrics (at most 16) are kept as they are."""

    model_config = ConfigDict(
        extra="allow",
        json_schema_extra={
            "additionalProperties": {"type": "number", "minimum": -1e300, "maximum": 1e300},
            "propertyNames": {"maxLength": 64, "pattern": METRIC_NAME_PATTERN},
            "maxProperties": 4 + MAX_EXTRA_METRICS,
        },
    )

    step: Count = Field(ge=0, le=10**12)
    # NaN/Infinity: "should be a finite number", not a bound's message
    success: Annotated[
        float, Field(ge=0.0, le=1.0, allow_inf_nan=False), _METRIC
    ] | None = None
    time: Annotated[float, Field(ge=0.0, le=1e9, allow_inf_nan=False), _METRIC] | None = None
    cost: Annotated[
        float, Field(ge=-1e12, le=1e12, allow_inf_nan=False), _METRIC
    ] | None = None

    @model_validator(mode="after")
    def _extra(self) -> ProgressCreate:
        extra = self.model_extra or {}
        if len(extra) > MAX_EXTRA_METRICS:
            raise ValueError(f"at most {MAX_EXTRA_METRICS} extra metrics")
        for k, v in extra.items():
            _metric_name(k)
            if len(k) > 64 or isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"extra metric {k[:64]!r} must be a number with a short name")
            if abs(v) > 1e300 or not math.isfinite(v):  # NaN, Infinity, 1e400; huge integers
                raise ValueError(f"extra metric {k[:64]!r} must be a finite number in "
                                 "[-1e300, 1e300]")
        return self


def _metric_name(k: str) -> None:
    """:data:`METRIC_NAME_PATTERN`, its bad characters named."""
    bad = sorted({f"U+{ord(c):04X}" for c in _METRIC_NAME_FORMAT.findall(k)})
    try:
        _printable(k)
        if bad:
            raise ValueError(f"format characters are not allowed: {', '.join(bad[:5])}")
    except ValueError as exc:
        raise ValueError(f"extra metric name {k[:64]!r}: {exc}") from None


class ProgressPublic(BaseModel):
    worker: str
    step: int
    success: float | None
    time: float | None
    cost: float | None
    extra: dict[str, Any] | None


class TaskReviewCreate(BaseModel):
    model_config = WRITE_BODY

    worker: Address
    review: Review
    accepted: Flag = True


class OutcomeTrialPublic(ExpertTrialPublic):
    """The worker's trial of an expert on the task after its run (its outcome's card,
    ``training.experts.review``): the evidence for the requester's review of the expert."""

    worker: str = Field(description="the worker whose outcome card says so (its word)")


class TaskExpertPublic(BaseModel):
    """An expert model the task's spec names (MEDC), with what the index knows of it."""

    cid: str
    qos: float | None = Field(description="QoS weight in the spec (null: equal weights)")
    model_id: int | None = Field(description="its MMC model, when listed")
    reputation: float | None = Field(description="the model's Eq. 11 reputation")
    alloc_id: int | None = Field(description="the requester's latest allocation of it")
    review: int | None = Field(description="the requester's review in that allocation")
    trials: list[OutcomeTrialPublic] = Field(
        default_factory=list,
        description="the worker's trial of it on the task after the run, one per outcome "
        "whose card has one: figures and a suggested 0-5 review",
    )

    @computed_field(  # type: ignore[prop-decorator]
        description="the review the trials suggest together: their middle suggestion (the "
        "lower middle for an even count), null without trials"
    )
    @property
    def suggested_review(self) -> int | None:
        return middle_review([t.suggested_review for t in self.trials])


SpecState = Literal["pending", "read", "none", "invalid", "missing"]


class TaskDetailPublic(TaskPublic):
    spec: dict[str, Any] | None
    spec_state: SpecState = Field(
        default="read",
        description="where the spec stands in the index: pending (not read from the store yet), "
        "read, none (the description is no CID), invalid (not a task spec), missing (the "
        "store did not find it)",
    )
    experts: list[TaskExpertPublic] = Field(default_factory=list)
    timeline: list[EventPublic]
    offers: list[OfferPublic]
    outcomes: list[OutcomePublic]
    progress: list[ProgressPublic]


TasksPublic = ListPublic[TaskPublic]
