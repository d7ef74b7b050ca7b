"""Field rules of the task spec that both check a JSON value and describe it as JSON Schema.

One rule object per field is the single source of its bounds: ``check`` enforces them when a
document is parsed (raising :class:`SpecError` with the dotted field name) and ``schema``
publishes the same bounds in the OpenAPI document, so clients, the web form and schemathesis
see exactly what the parser accepts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any


class SpecError(ValueError):
    """A task spec that cannot be trained: ``field`` is the dotted path of the bad field
    (``env.intensity``, ``budget``), ``msg`` says why."""

    def __init__(self, field: str, msg: str) -> None:
        super().__init__(f"{field}: {msg}")
        self.field = field
        self.msg = msg


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


@dataclass(frozen=True)
class Int:
    lo: int
    hi: int
    doc: str = ""
    odd: bool = False

    def check(self, v: Any, field: str) -> int:
        # JSON Schema's integer includes 2.0 (a number with no fraction); so does this rule
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        if not _is_int(v):
            raise SpecError(field, f"expected an integer, got {v!r}")
        if not self.lo <= v <= self.hi:
            raise SpecError(field, f"must be in [{self.lo}, {self.hi}], got {v}")
        if self.odd and v % 2 == 0:
            raise SpecError(field, f"must be odd, got {v}")
        return int(v)

    def schema(self) -> dict[str, Any]:
        s: dict[str, Any] = {"type": "integer", "minimum": self.lo, "maximum": self.hi}
        if self.odd:
            s["not"] = {"multipleOf": 2}
        return _doc(s, self.doc)


@dataclass(frozen=True)
class Real:
    """A finite number in [lo, hi] (NaN and infinities are never accepted)."""

    lo: float
    hi: float
    doc: str = ""

    def check(self, v: Any, field: str) -> float:
        if not _is_number(v):
            raise SpecError(field, f"expected a number, got {v!r}")
        try:
            v = float(v)
        except OverflowError:  # an integer of hundreds of digits: JSON allows it
            raise SpecError(field, f"must be a number in [{self.lo:g}, {self.hi:g}], got an "
                            f"integer of {v.bit_length()} bits") from None
        if not math.isfinite(v) or not self.lo <= v <= self.hi:
            raise SpecError(field, f"must be a number in [{self.lo:g}, {self.hi:g}], got {v!r}")
        return v

    def schema(self) -> dict[str, Any]:
        return _doc({"type": "number", "minimum": self.lo, "maximum": self.hi}, self.doc)


@dataclass(frozen=True)
class Choice:
    values: tuple[Any, ...]
    doc: str = ""

    def check(self, v: Any, field: str) -> Any:
        # JSON Schema's enum compares numbers by value: 8.0 is the choice 8 (as for Int)
        if isinstance(v, float) and v.is_integer() and any(_is_int(c) for c in self.values):
            v = int(v)
        # bool is an int in Python: 4 must not match True, True must not match 1
        if not any(v == c and type(v) is type(c) for c in self.values):
            raise SpecError(field, f"must be one of {list(self.values)}, got {v!r}")
        return v

    def schema(self) -> dict[str, Any]:
        return _doc({"enum": list(self.values)}, self.doc)


@dataclass(frozen=True)
class Bool:
    doc: str = ""

    def check(self, v: Any, field: str) -> bool:
        if not isinstance(v, bool):
            raise SpecError(field, f"expected true or false, got {v!r}")
        return v

    def schema(self) -> dict[str, Any]:
        return _doc({"type": "boolean"}, self.doc)


@dataclass(frozen=True)
class Pair:
    """Two values of one rule as a JSON array ``[a, b]``; ``ordered`` requires a <= b."""

    item: Int | Real
    ordered: bool = True
    doc: str = ""

    def check(self, v: Any, field: str) -> tuple[Any, Any]:
        if not isinstance(v, list | tuple) or len(v) != 2:
            raise SpecError(field, f"expected a pair [a, b], got {v!r}")
        a, b = (self.item.check(x, f"{field}[{i}]") for i, x in enumerate(v))
        if self.ordered and a > b:
            raise SpecError(field, f"expected [min, max] with min <= max, got {list(v)}")
        return a, b

    def schema(self) -> dict[str, Any]:
        s = {"type": "array", "items": self.item.schema(), "minItems": 2, "maxItems": 2}
        return _doc(s, self.doc)


@dataclass(frozen=True)
class Nullable:
    rule: Any

    def check(self, v: Any, field: str) -> Any:
        return None if v is None else self.rule.check(v, field)

    def schema(self) -> dict[str, Any]:
        return {"anyOf": [self.rule.schema(), {"type": "null"}]}


def check_object(doc: Any, rules: dict[str, Any], field: str) -> dict[str, Any]:
    """Check every present key of ``doc`` against ``rules`` (unknown keys are an error)."""
    if not isinstance(doc, dict):
        raise SpecError(field or "spec", f"expected an object, got {type(doc).__name__}")
    for key in doc:
        if key not in rules:
            raise SpecError(join(field, key), f"unknown field (known: {sorted(rules)})")
    return {k: rules[k].check(v, join(field, k)) for k, v in doc.items()}


def join(field: str, key: str) -> str:
    """Dotted path of ``key`` inside ``field`` ("" is the document itself)."""
    return f"{field}.{key}" if field else key


def object_schema(rules: dict[str, Any], doc: str = "", **extra: Any) -> dict[str, Any]:
    s = {
        "type": "object",
        "properties": {k: r.schema() for k, r in rules.items()},
        "additionalProperties": False,
        **extra,
    }
    return _doc(s, doc)


def _doc(s: dict[str, Any], doc: str) -> dict[str, Any]:
    if doc:
        s["description"] = doc
    return s
