from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field, WithJsonSchema

from workers.mdrl.trainingspec import trainingspec_json_schema

from .cards import (
    CurvePointPublic,
    ExpertUsagePublic,
    FinalEvalPublic,
    HeldoutPublic,
    TrainedPublic,
)
from .common import (
    JSON_NUMBER_ONLY,
    MAX_ID,
    WRITE_BODY,
    CidStr,
    Count,
    Domain,
    Fraction,
    ListPublic,
    PlainText,
    Review,
    Wei,
)

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

    model_config = WRITE_BODY

    cid: CidStr
    description: PlainText = Field(default="", max_length=1024)
    domain: Domain = 0
    env: EnvDocument = Field(description="EnvSpec the model was trained on (its card's env)")


class CommitmentCreate(BaseModel):
    """TMC.commitCid by the caller: keccak256(cid ++ caller), made before the CID is uploaded
    anywhere others read (commit-reveal of CIDs); the CID itself is not sent."""

    model_config = WRITE_BODY

    commitment: str = Field(
        pattern=r"^0x[0-9a-fA-F]{64}$",
        description="keccak256 of the CID's UTF-8 bytes followed by the caller's 20-byte address",
    )


class CommitmentPublic(BaseModel):
    commitment: str
    block: int = Field(description="block of the commitment; a reveal needs a later one")


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


class ProducedByPublic(BaseModel):
    """The training task whose outcome this model is: the TMC records each outcome CID once
    with its task and worker (``outcomeOf``), indexed as the task's outcome, so this link is
    the chain's, not the card's."""

    task_id: int
    worker: str
    review: int | None
    accepted: bool | None
    source: Literal["chain"] = "chain"


class ExpertPublic(BaseModel):
    """A model this one learned from (MEDC/DC experts)."""

    ref: str = Field(description="the expert as given: a CID, or a name the card gives")
    cid: str | None = Field(description="the expert's CID, when ref is one")
    model_id: int | None = Field(description="the expert's model id when it is on the platform")
    source: Literal["card", "task_spec"] = Field(
        description="card: training.experts of the model's card (the owner's word); task_spec: "
        "the experts of the producing task's spec (its CID is on chain)"
    )
    usage: ExpertUsagePublic | None = Field(
        default=None,
        description="what the model's card says the run did with this expert (guided "
        "episodes, decisions, followed); null when the card does not say",
    )


class ModelRequestPublic(BaseModel):
    """A model-sharing task (MMC.allocateModel) that returned this model."""

    alloc_id: int
    requester: str
    qos: float = Field(description="the model's QoS in that allocation, in [0, 1]")
    price_wei: str
    price_eth: str = Field(description="price_wei in ETH, an exact decimal string")
    review: int | None


class ModelDetailPublic(ModelPublic):
    description: str
    card: dict[str, Any] | None
    metrics: Any | None
    owner_reputation: float = Field(
        description="the owner's model-sharing reputation (Eq. 19, the UMC's sharing counters: "
        "the Eq. 22-23 allocations filter on it)"
    )
    owner_rating: float = Field(description="the owner's model-sharing rating (Eq. 19's rating)")
    owner_model_reputation: float = Field(
        description="the owner's Eq. 10 reputation: reviews over allocations of all its models "
        "(the MMC's OwnerRecord; Eq. 10-13 allocations filter on it; 0.5 before any)"
    )
    name: str | None = Field(default=None, description="the card's name (zoo models)")
    kind: str | None = Field(default=None, description="ODMTL, DMTL or CMTL (the card's)")
    env_spec: dict[str, Any] | None = Field(
        default=None, description="the card's EnvSpec, when it parses (bounds of a task spec)"
    )
    curve: list[CurvePointPublic] = Field(
        default_factory=list, description="the card's training curve (workers/mdrl/curve.py)"
    )
    curve_updates: int | None = None
    heldout: HeldoutPublic | None = None
    final_eval: FinalEvalPublic | None = None
    trained: TrainedPublic | None = None
    produced_by: ProducedByPublic | None = None
    experts: list[ExpertPublic] = Field(default_factory=list)
    requests: list[ModelRequestPublic] = Field(
        default_factory=list, description="the latest model-sharing tasks that returned it"
    )


class ModelRequestCreate(BaseModel):
    """A model-sharing task (MMC.allocateModel)."""

    model_config = WRITE_BODY

    domain: Domain = 0
    env: EnvDocument = Field(description="EnvSpec the models should fit")
    num_models: Count = Field(default=1, ge=1, le=16)
    metric: Literal["model", "sharing"] = "sharing"
    min_reputation: Fraction = 0.0
    min_rating: Fraction = 0.0
    min_model_reputation: Fraction = 0.0
    price_wei: Wei(80) | None = Field(  # type: ignore[valid-type]
        default=None,
        description="wei paid per model to its owner; none = the MMC's minimum price "
        "(minModelPrice, set by the consortium; a lower price is a 422 price_below_minimum)",
    )
    weights: list[Annotated[int, Field(ge=0, le=WEIGHT_ONE), JSON_NUMBER_ONLY]] = Field(
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
    model_config = WRITE_BODY

    model_id: Count = Field(ge=1, le=MAX_ID)
    review: Review


ModelsPublic = ListPublic[ModelPublic]
AllocationsPublic = ListPublic[AllocationDetailPublic]
