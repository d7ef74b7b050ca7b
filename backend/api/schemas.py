"""Shared request/response types. Resource schemas follow ``XCreate`` / ``XPublic`` /
``XsPublic{data, count}`` (STYLE.md) in their routers' modules."""

from __future__ import annotations

from typing import Annotated

from pydantic import AfterValidator, Field

from backend.auth import checksum

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
