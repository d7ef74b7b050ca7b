"""Shared request/response types of the routers. Resource schemas follow ``XCreate`` /
``XPublic`` / ``XsPublic{data, count}`` (STYLE.md); the field types live in
``backend.schemas.common`` (below the API, so services can use them too)."""

from backend.schemas.common import Address

__all__ = ["Address"]
