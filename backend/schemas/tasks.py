from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from .common import Address, Domain, EventPublic, Fraction, ListPublic, Review, Wei

MAX_EXTRA_METRICS = 16


class ObservationIn(BaseModel):
    kind: Literal["odmtl", "dmtl", "cmtl"] = "odmtl"
    window: int = Field(default=3, ge=3, le=63, description="odd, < min(rows, cols) for odmtl")

    @field_validator("window")
    @classmethod
    def _odd(cls, v: int) -> int:
        if v % 2 == 0:
            raise ValueError("window must be odd")
        return v


class BudgetIn(BaseModel):
    steps: int = Field(ge=1_000, le=100_000_000, description="environment steps to train")
    minutes: int = Field(ge=1, le=10_080, description="wall-clock cap (at most a week)")


class TaskCreate(BaseModel):
    """A training task (docs/platform.md): the spec goes to the content store, its CID on chain."""

    env: dict[str, Any] = Field(description="EnvSpec fields (workers.mdrl.spec.EnvSpec)")
    observation: ObservationIn = ObservationIn()
    budget: BudgetIn
    seed: int = Field(default=0, ge=0, le=2**32 - 1)
    domain: Domain = 0
    num_workers: int = Field(default=1, ge=1, le=16)
    min_reputation: Fraction = 0.0
    min_rating: Fraction = 0.0
    min_cpu_cores: int = Field(default=0, ge=0, le=65_535)
    min_ram_gb: int = Field(default=0, ge=0, le=65_535)
    deadline_s: int = Field(default=86_400, ge=60, le=2**32 - 1)
    payment_wei: Wei(96) = Field(default=0, description="reward per worker, escrowed")  # type: ignore[valid-type]

    @field_validator("env")
    @classmethod
    def _small(cls, v: dict[str, Any]) -> dict[str, Any]:
        if len(v) > 32:
            raise ValueError("env has too many fields")
        return v


class TaskCreatedPublic(BaseModel):
    task_id: int
    spec_cid: str
    offered: list[str]
    tx_hashes: list[str]


class TaskPublic(BaseModel):
    id: int
    requester: str
    domain: int
    status: str
    num_workers: int
    reward_wei: str
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


class ProgressCreate(BaseModel):
    """A training-curve point; extra numeric metrics (at most 16) are kept as they are."""

    model_config = ConfigDict(extra="allow")

    step: int = Field(ge=0, le=10**12)
    success: float | None = Field(default=None, ge=0.0, le=1.0)
    time: float | None = Field(default=None, ge=0.0, le=1e9)
    cost: float | None = Field(default=None, ge=-1e12, le=1e12)

    @model_validator(mode="after")
    def _extra(self) -> ProgressCreate:
        extra = self.model_extra or {}
        if len(extra) > MAX_EXTRA_METRICS:
            raise ValueError(f"at most {MAX_EXTRA_METRICS} extra metrics")
        for k, v in extra.items():
            if len(k) > 64 or isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"extra metric {k[:64]!r} must be a number with a short name")
        return self


class ProgressPublic(BaseModel):
    worker: str
    step: int
    success: float | None
    time: float | None
    cost: float | None
    extra: dict[str, Any] | None


class TaskReviewCreate(BaseModel):
    worker: Address
    review: Review
    accepted: bool = True


class TaskDetailPublic(TaskPublic):
    spec: dict[str, Any] | None
    timeline: list[EventPublic]
    offers: list[OfferPublic]
    outcomes: list[OutcomePublic]
    progress: list[ProgressPublic]


TasksPublic = ListPublic[TaskPublic]
