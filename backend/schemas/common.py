"""Shared field types: bounded ints, QoS fractions, wei amounts, CIDs, list wrapper."""

from __future__ import annotations

import unicodedata
from typing import Annotated, Any, Generic, TypeVar

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field

from backend.chain.addresses import checksum
from backend.chain.platform import MAX_DOMAIN
from backend.store import CID, InvalidCID

__all__ = [
    "MAX_DOMAIN",
    "MAX_ID",
    "CID_PATTERN",
    "Address",
    "CidStr",
    "Domain",
    "EventPublic",
    "Flag",
    "json_number_only",
    "Fraction",
    "ID_DIGITS",
    "ListPublic",
    "Review",
    "TxPublic",
    "Wei",
    "WRITE_BODY",
    "wei_to_eth",
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

WRITE_BODY = ConfigDict(extra="forbid")
"""``model_config`` of a request body that writes: a field it does not know is a 422 naming it
(``extra_forbidden``), not left out. Read as its default, a misspelt field acts otherwise than
asked: ``{"review": 0, "accept": false}`` paid the outcome it meant to reject
(``accepted`` defaults to true), ``"num_model": 3`` bought one model."""

ONE = 1_000_000  # QoS fixed point of the contracts (backend.chain.qos)
T = TypeVar("T")


def _not_bool(v: Any) -> Any:
    if isinstance(v, bool):
        raise ValueError("a count is a number, not true/false")
    if isinstance(v, str):
        raise ValueError("a count is a JSON number, not a string")
    return v


def json_number_only(what: str) -> BeforeValidator:
    """Refuse ``true``/``false`` and strings for a number field (pydantic's lax mode reads
    true as 1 and "0.5" as 0.5), the message naming ``what`` the field holds."""

    def check(v: Any) -> Any:
        if isinstance(v, bool):
            raise ValueError(f"{what} is a number, not true/false")
        if isinstance(v, str):
            raise ValueError(f"{what} is a JSON number, not a string")
        return v

    return BeforeValidator(check)


def _json_bool(v: Any) -> Any:
    if not isinstance(v, bool):
        raise ValueError("a flag is JSON true or false, not a number or a string")
    return v


JSON_NUMBER_ONLY = BeforeValidator(_not_bool)
"""Put after a ``Field`` with bounds (before it, pydantic writes ge/le into the schema, not
minimum/maximum)."""
Count = Annotated[int, JSON_NUMBER_ONLY]
"""An integer as JSON Schema has it (``3`` or ``3.0``), but never ``true`` or ``"3"``:
pydantic's lax int takes a boolean as 0 or 1 and a numeric string as its number."""
Domain = Annotated[
    int,
    Field(ge=0, le=MAX_DOMAIN, description=f"domain code 0-{MAX_DOMAIN}"),
    JSON_NUMBER_ONLY,
]
Review = Annotated[
    int, Field(ge=0, le=5, description="review score 0-5"), JSON_NUMBER_ONLY
]
Fraction = Annotated[
    float,
    Field(ge=0.0, le=1.0, allow_inf_nan=False, description="QoS value in [0, 1]"),
    json_number_only("a fraction"),
]
"""A QoS value as JSON Schema has it: ``0.5``, never ``true`` or ``"0.5"``; NaN is "should be
a finite number", not a bound it does not break ("should be less than or equal to 1")."""
JSON_BOOL_ONLY = BeforeValidator(_json_bool)
"""A JSON boolean only: pydantic's lax bool reads 0/1 and "yes"/"no" as flags."""
Flag = Annotated[bool, JSON_BOOL_ONLY]


def _check_cid(v: str) -> str:
    try:
        CID.parse(v)
    except InvalidCID as exc:
        raise ValueError(f"not a CID: {exc}") from None
    return v


CID_PATTERN = r"^b(?:afkrei|afybei)[a-h][a-z2-7]{50}[aeimquy4]$"
"""A CID as the content store writes it: CIDv1, sha2-256, codec raw (``bafkrei``) or dag-pb
(``bafybei``), multibase base32 lower case. The 8th character carries the digest's first 3 bits
and the last one its final 3 bits plus 2 zero padding bits, so every string that matches is a
CID the store can parse (and writes back identically)."""
CID_LENGTH = 59

CidStr = Annotated[
    str,
    Field(
        min_length=CID_LENGTH,
        max_length=CID_LENGTH,
        pattern=CID_PATTERN,
        description="CIDv1 (sha2-256, raw or dag-pb, base32 ``b...``)",
        examples=["bafkreihdwdcefgh4dqkjv67uzcmw7ojee6xedzdetojuzjevtenxquvyku"],
    ),
    AfterValidator(_check_cid),
]


MAX_ID = 10**18
"""Bound of a resource id (task, model, allocation): far above any id, below SQLite's int64,
and a power of ten, which JSON tools that read numbers as doubles read exactly."""


def _digits(v: Any) -> Any:
    if isinstance(v, str) and not (v.isascii() and v.isdigit()):
        raise ValueError("an id is decimal digits only")
    return v


ID_DIGITS = BeforeValidator(_digits)
"""A resource id in a URL path is digits only (put after its ``Path``): pydantic's lax int
takes "1.0" and " 1", so one resource would have many URLs."""


MAX_EXACT_FLOAT = 2**53
"""Integers below this are exact as a JSON number with a decimal point or an exponent (read
as a double); from it on such a number may be a neighbouring integer rounded to it."""


def _exact_wei(v: Any) -> Any:
    if isinstance(v, float) and abs(v) >= MAX_EXACT_FLOAT:
        raise ValueError(
            f"an amount of wei from 2^53 on is a JSON integer (digits only): {v!r}, with a "
            "decimal point or an exponent, is read as a rounded double"
        )
    return v


def Wei(upper_bits: int) -> Any:  # noqa: N802 - a type factory
    """An amount of wei at most the largest power of ten below 2^``upper_bits`` (so it fits the
    contract's uint): a bound like 2^96 becomes a rounded double in JSON tools, and clients
    would then send values just above it as valid. From 2^53 on only as an integer literal:
    ``1.00000000000000001e17`` was escrowed as 1e17 wei, and ``1e23`` refused as "unable to
    parse input string as an integer" (of a string nobody sent)."""
    bound = 10 ** (len(str(2**upper_bits - 1)) - 1)
    return Annotated[
        int,
        Field(ge=0, le=bound, description=f"wei, at most 1e{len(str(bound)) - 1}"),
        BeforeValidator(_exact_wei),
        json_number_only("an amount of wei"),
    ]


def to_fixed(x: float) -> int:
    """[0, 1] -> contract fixed point (ONE = 1e6), to the nearest unit: 0.0642 is 64200, not
    the 64199 that truncating 0.0642 * 1e6 (64199.99...) gives."""
    return round(x * ONE)


def from_fixed(v: int) -> float:
    return v / ONE


WEI_PER_ETH = 10**18


def wei_to_eth(wei: int | str) -> str:
    """An amount of wei as an exact decimal string of ETH ("0.005", "12", "0.000000000000000001"):
    no float on the way, so the UI shows exactly what the chain holds."""
    whole, frac = divmod(int(wei), WEI_PER_ETH)
    digits = f"{frac:018d}".rstrip("0")
    return f"{whole}.{digits}" if digits else str(whole)


class ListPublic(BaseModel, Generic[T]):
    data: list[T]
    count: int = Field(description="rows matching the filters (before limit/offset)")


class EventPublic(BaseModel):
    """One indexed chain event (``chain_events`` row: ``EventPublic.model_validate(row)``)."""

    model_config = ConfigDict(from_attributes=True)

    block_number: int
    log_index: int
    tx_hash: str
    contract: str
    name: str
    args: dict[str, Any]
    block_time: int | None
    error: str | None = Field(
        default=None,
        description="why the index could not store this event's rows (it went on without "
        "them; the chain holds the event), else null",
    )


class TxPublic(BaseModel):
    """A mined platform transaction and its decoded events."""

    tx_hash: str
    block_number: int
    status: int
    events: list[dict[str, Any]]


def _printable(v: str) -> str:
    """Free text as every index and page can hold it: no control characters but newline and
    tab (PostgreSQL text cannot hold NUL at all; the others garble logs and pages)."""
    bad = sorted({f"U+{ord(c):04X}" for c in v if (ord(c) < 32 and c not in "\n\t")
                  or 0x7F <= ord(c) < 0xA0})
    if bad:
        raise ValueError(f"control characters are not allowed: {', '.join(bad[:5])}")
    return v


PLAIN_TEXT_PATTERN = r"^[^\u0000-\u0008\u000B-\u001F\u007F-\u009F]*$"
"""`_printable` as a JSON Schema pattern, so the OpenAPI document states the rule (the
validator, not this pattern, refuses, with the characters named)."""

PlainText = Annotated[
    str, AfterValidator(_printable), Field(json_schema_extra={"pattern": PLAIN_TEXT_PATTERN})
]
"""Free text of an API request (a model's description): control characters refused."""


def _visible(v: str) -> str:
    """:func:`_printable`, and no format character (Unicode Cf: bidi overrides such as U+202E,
    zero-width ones): in a line the page shows next to its own labels, an override reorders
    the label too (a card's expert ref posed as chain-backed provenance; audit of 2026-12-03)."""
    _printable(v)
    bad = sorted({f"U+{ord(c):04X}" for c in v if unicodedata.category(c) == "Cf"})
    if bad:
        raise ValueError(f"invisible format characters are not allowed: {', '.join(bad[:5])}")
    return v


VisibleText = Annotated[str, AfterValidator(_visible)]
"""Short text shown inline beside the page's own words (names, references)."""
