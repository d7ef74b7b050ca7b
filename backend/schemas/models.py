from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field, WithJsonSchema

from workers.mdrl.trainingspec import trainingspec_json_schema

from .common import MAX_ID, CidStr, Domain, Fraction, ListPublic, Review, Wei

EnvDocument = Annotated[
    dict[str, Any], WithJsonSchema(trainingspec_json_schema()["properties"]["env"])
]
"""An EnvSpec document: its JSON Schema is the core's (bounds included); the route parses it
with the core's parser, which names a bad field in the 422 (and checks the cross-field rules
JSON Schema cannot state, e.g. walls <= max(rows, cols))."""
ENV_ATTRIBUTE_COUNT = 6
"""Length of the MMC env vector (backend.services.specs.ENV_ATTRIBUTES)."""
WEIGHT_ONE = 1_000_000
"""Fixed point of the Eq. 13/22 weights: one weight per env attribute, summing to this."""


class ModelCreate(BaseModel):
    """Share a model the caller owns (MMC.addModel); ``cid`` is its bundle manifest."""

    cid: CidStr
    description: str = Field(default="", max_length=1024)
    domain: Domain = 0
    env: EnvDocument = Field(description="EnvSpec the model was trained on (its card's env)")


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
    env: EnvDocument = Field(description="EnvSpec the models should fit")
    num_models: int = Field(default=1, ge=1, le=16)
    metric: Literal["model", "sharing"] = "sharing"
    min_reputation: Fraction = 0.0
    min_rating: Fraction = 0.0
    min_model_reputation: Fraction = 0.0
    price_wei: Wei(80) | None = Field(  # type: ignore[valid-type]
        default=None,
        description="wei paid per model to its owner; none = the MMC's minimum price "
        "(minModelPrice, set by the consortium; a lower price is a 422 price_below_minimum)",
    )
    weights: list[Annotated[int, Field(ge=0, le=WEIGHT_ONE)]] = Field(
        default_factory=list,
        max_length=ENV_ATTRIBUTE_COUNT,
        description=f"none (equal weights) or one per env attribute, in fixed point summing to "
        f"{WEIGHT_ONE}",
        json_schema_extra={
            "anyOf": [{"maxItems": 0}, {"minItems": ENV_ATTRIBUTE_COUNT}],
        },
    )


class AllocatedModelPublic(BaseModel):
    id: int
    cid: str
    qos: float


class ModelAllocationPublic(BaseModel):
    alloc_id: int
    models: list[AllocatedModelPublic]


class AllocationModelPublic(AllocatedModelPublic):
    owner: str
    review: int | None = Field(description="the requester's review (0-5), null until reviewed")


class AllocationDetailPublic(BaseModel):
    """A model-sharing allocation (MMC.allocateModel) as indexed: what the requester paid for
    and the models it received, each with its QoS (Eq. 13 / 22-23) and review."""

    alloc_id: int
    requester: str
    domain: int
    metric: Literal["model", "sharing"]
    num_models: int
    price_wei: str
    block_number: int
    models: list[AllocationModelPublic]


class ModelReviewCreate(BaseModel):
    model_id: int = Field(ge=1, le=MAX_ID)
    review: Review


ModelsPublic = ListPublic[ModelPublic]
AllocationsPublic = ListPublic[AllocationDetailPublic]
