from __future__ import annotations

from pydantic import BaseModel

from .common import ListPublic


class CountersPublic(BaseModel):
    assigned: int
    accepted: int
    completed: int
    rating_sum: int
    rating_count: int


class DomainCountersPublic(CountersPublic):
    domain: int
    task_type: str


class WorkerPublic(BaseModel):
    address: str
    worker_id: int
    status: str
    domains: list[int]
    cpu_cores: int
    ram_gb: int
    gpu_series: int
    reputation: float
    rating: float
    sharing_reputation: float
    sharing_rating: float
    counters: CountersPublic


class WorkerDetailPublic(WorkerPublic):
    by_domain: list[DomainCountersPublic]


WorkersPublic = ListPublic[WorkerPublic]
