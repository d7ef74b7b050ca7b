"""Shared request/response types of the routers. Resource schemas follow ``XCreate`` /
``XPublic`` / ``XsPublic{data, count}`` (STYLE.md); the field types live in
``backend.schemas.common`` (below the API, so services can use them too)."""

from typing import Annotated

from fastapi import Query

from backend.schemas.common import Address

__all__ = ["Address", "FractionQuery"]

FractionQuery = Annotated[
    float | None, Query(ge=0, le=1, allow_inf_nan=False, description="a fraction in [0, 1]")
]
"""A [0, 1] filter in a query string (``?min_reputation=0.5``): ``nan`` is "should be a finite
number", not "should be less than or equal to 1" (``backend.schemas.common.Fraction`` for
bodies)."""
