from __future__ import annotations

from pydantic import BaseModel, Field, field_validator

from .common import WRITE_BODY, Count, Domain

MAX_WORKER_DOMAINS = 4
"""UMC.MAX_WORKER_DOMAINS: one registration joins at most four domains' candidate queues."""


class WorkerCreate(BaseModel):
    """Register (or update the capabilities of) the caller as a worker (UMC.addWorker)."""

    model_config = WRITE_BODY

    domains: list[Domain] = Field(
        min_length=1, max_length=MAX_WORKER_DOMAINS, json_schema_extra={"uniqueItems": True}
    )
    cpu_cores: Count = Field(ge=1, le=65_535)
    ram_gb: Count = Field(ge=0, le=65_535)
    gpu_series: Count = Field(default=0, ge=0, le=255, description="GPU series code, 0 = no GPU")

    @field_validator("domains")
    @classmethod
    def _unique(cls, v: list[int]) -> list[int]:
        if len(set(v)) != len(v):
            raise ValueError("domains must not repeat")
        return sorted(v)


class RegistrationPublic(BaseModel):
    address: str
    role: str
    tx_hash: str | None
    created: bool = Field(description="false when only capabilities were updated")
    status: str | None = Field(
        default=None,
        description="status after the call: active, idle (workers only), pending (waiting "
        "for a consortium admin's approval) or removed",
    )
