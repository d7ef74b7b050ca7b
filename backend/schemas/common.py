"""Shared field types: bounded ints, QoS fractions, wei amounts, CIDs, list wrapper."""

from __future__ import annotations

from typing import Annotated, Any, Generic, TypeVar

from pydantic import AfterValidator, BaseModel, Field

from backend.chain.addresses import checksum
from backend.chain.platform import MAX_DOMAIN
from backend.store import CID, InvalidCID

__all__ = [
    "MAX_DOMAIN",
    "Address",
    "CidStr",
    "Domain",
    "EventPublic",
    "Fraction",
    "ListPublic",
    "Review",
    "TxPublic",
    "Wei",
]

Address = Annotated[
    str,
    Field(
        description="Ethereum address (0x + 40 hex digits; returned EIP-55 checksummed)",
        examples=["0x7E5F4552091A69125d5DfCb7b8C2659029395Bdf"],
        min_length=42,
        max_length=42,
        pattern=r"^0x[0-9a-fA-F]{40}$",
    ),
    AfterValidator(checksum),
]

ONE = 1_000_000  # QoS fixed point of the contracts (backend.chain.qos)
T = TypeVar("T")

Domain = Annotated[int, Field(ge=0, le=MAX_DOMAIN, description=f"domain code 0-{MAX_DOMAIN}")]
Review = Annotated[int, Field(ge=0, le=5, description="review score 0-5")]
Fraction = Annotated[float, Field(ge=0.0, le=1.0, description="QoS value in [0, 1]")]


def _check_cid(v: str) -> str:
    try:
        CID.parse(v)
    except InvalidCID as exc:
        raise ValueError(f"not a CID: {exc}") from None
    return v


CidStr = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(_check_cid)]


def Wei(upper_bits: int) -> Any:  # noqa: N802 - a type factory
    return Annotated[int, Field(ge=0, lt=2**upper_bits, description=f"wei (< 2^{upper_bits})")]


def to_fixed(x: float) -> int:
    """[0, 1] -> contract fixed point (ONE = 1e6), rounded down."""
    return int(x * ONE)


def from_fixed(v: int) -> float:
    return v / ONE


class ListPublic(BaseModel, Generic[T]):
    data: list[T]
    count: int = Field(description="rows matching the filters (before limit/offset)")


class EventPublic(BaseModel):
    block_number: int
    log_index: int
    tx_hash: str
    contract: str
    name: str
    args: dict[str, Any]
    block_time: int | None


class TxPublic(BaseModel):
    """A mined platform transaction and its decoded events."""

    tx_hash: str
    block_number: int
    status: int
    events: list[dict[str, Any]]
