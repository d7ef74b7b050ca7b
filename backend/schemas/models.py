from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

from .common import CidStr, Domain, Fraction, ListPublic, Review, Wei


class ModelCreate(BaseModel):
    """Share a model the caller owns (MMC.addModel); ``cid`` is its bundle manifest."""

    cid: CidStr
    description: str = Field(default="", max_length=1024)
    domain: Domain = 0
    env: dict[str, Any] = Field(description="EnvSpec the model was trained on")


class ModelPublic(BaseModel):
    id: int
    cid: str
    owner: str
    domain: int
    env: list[int]
    agents: int | None
    walls_min: int | None
    walls_max: int | None
    reputation: float
    allocations: int
    rating: float


class ModelDetailPublic(ModelPublic):
    description: str
    card: dict[str, Any] | None
    metrics: Any | None
    owner_reputation: float
    owner_rating: float


class ModelRequestCreate(BaseModel):
    """A model-sharing task (MMC.allocateModel)."""

    domain: Domain = 0
    env: dict[str, Any]
    num_models: int = Field(default=1, ge=1, le=16)
    metric: Literal["model", "sharing"] = "sharing"
    min_reputation: Fraction = 0.0
    min_rating: Fraction = 0.0
    min_model_reputation: Fraction = 0.0
    price_wei: Wei(80) = 0  # type: ignore[valid-type]
    weights: list[int] = Field(default_factory=list, max_length=64)


class AllocatedModelPublic(BaseModel):
    id: int
    cid: str
    qos: float


class ModelAllocationPublic(BaseModel):
    alloc_id: int
    models: list[AllocatedModelPublic]


class ModelReviewCreate(BaseModel):
    model_id: int = Field(ge=1, le=2**63 - 1)
    review: Review


ModelsPublic = ListPublic[ModelPublic]
