"""Off-chain documents the gateway writes to the content store, and their on-chain encodings.

* task spec (``drlaas-task/1``): a ``workers.mdrl.trainingspec.TrainingSpec`` document (the
  core owns its rules; here are the platform limits on its resource estimate). Its CID is the
  task's on-chain ``description`` (docs/platform.md, "Task spec"), so anyone can fetch it and
  check it against the chain.
* model bundle: see ``backend.store.bundle`` (the MMC stores the manifest's CID; the download
  endpoint resolves a file through it and streams its bytes verified against its own CID).
* environment attributes (MMC ``env``, Table 5.2): ``ENV_ATTRIBUTES`` of an EnvSpec as
  uint32, the vector the Eq. 13/22 distance compares.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from backend.store import ContentStore
from workers.mdrl.resources import ResourceEstimate, estimate
from workers.mdrl.spec import EnvSpec
from workers.mdrl.trainingspec import SpecError, parse_env

__all__ = [
    "ENV_ATTRIBUTES",
    "SpecError",
    "SpecLimitExceeded",
    "check_limits",
    "field_loc",
    "validate_env",
]

ENV_ATTRIBUTES = ("rows", "cols", "agents", "moves", "walls_min", "walls_max")
"""Order of the on-chain env attribute vector (uint32 each)."""


class SpecLimitExceeded(Exception):
    """A valid spec beyond a platform limit: ``rule`` names the limit, ``msg`` the figures."""

    def __init__(self, rule: str, msg: str) -> None:
        super().__init__(f"{rule}: {msg}")
        self.rule = rule
        self.msg = msg


def validate_env(env: Any) -> EnvSpec:
    """An EnvSpec document checked against the task-spec bounds; SpecError names the field
    relative to the env object (``rows``, ``intensity.values[0]``)."""
    return parse_env(env, field="")


def field_loc(field: str) -> tuple[str | int, ...]:
    """``env.intensity.values[0]`` -> ("env", "intensity", "values", 0) (a 422 ``loc``)."""
    loc: list[str | int] = []
    for part in field.split("."):
        m = re.fullmatch(r"([^\[]*)((?:\[\d+\])*)", part)
        name, idx = (m.group(1), m.group(2)) if m else (part, "")
        if name:
            loc.append(name)
        loc.extend(int(i) for i in re.findall(r"\d+", idx))
    return tuple(loc)


def check_limits(
    spec: Any,
    *,
    num_workers: int,
    max_memory_bytes: int,
    max_worker_hours: float,
    experts: Sequence[tuple[Any, Any]] = (),
    walls_cae: dict[str, Any] | None = None,
) -> ResourceEstimate:
    """The resource estimate of ``spec`` (with its experts' and walls CAE's nets when their
    cards are given), or :class:`SpecLimitExceeded` naming the limit."""
    est = estimate(spec, experts=experts, walls_cae=walls_cae)
    if est.memory_bytes > max_memory_bytes:
        raise SpecLimitExceeded(
            "spec_exceeds_memory_limit",
            f"training this spec needs about {_gib(est.memory_bytes)} of memory per worker "
            f"(largest part: {max(est.memory_parts, key=est.memory_parts.__getitem__)}); "
            f"the platform limit is {_gib(max_memory_bytes)}",
        )
    total = est.hours * num_workers
    if total > max_worker_hours:
        raise SpecLimitExceeded(
            "spec_exceeds_worker_hours_limit",
            f"the budget is about {est.hours:.3g} h per worker x {num_workers} workers = "
            f"{total:.3g} worker-hours; the platform limit is {max_worker_hours:g}",
        )
    return est


def _gib(n: int) -> str:
    return f"{n / 2**30:.3g} GiB"


def env_attributes(spec: Any) -> list[int]:
    """The MMC env vector of an EnvSpec, in :data:`ENV_ATTRIBUTES` order."""
    return [spec.rows, spec.cols, spec.agents, spec.moves, spec.walls[0], spec.walls[1]]


@dataclass(frozen=True)
class EnvSummary:
    agents: int | None
    walls_min: int | None
    walls_max: int | None


def summarize_env(attrs: list[int]) -> EnvSummary:
    """Searchable fields of an on-chain env vector (None where a shorter vector lacks them)."""

    def at(name: str) -> int | None:
        i = ENV_ATTRIBUTES.index(name)
        return int(attrs[i]) if len(attrs) > i else None

    return EnvSummary(at("agents"), at("walls_min"), at("walls_max"))


def load_json_doc(store: ContentStore, cid: str, *, max_size: int, fmt: str) -> dict[str, Any]:
    """Fetch a small JSON document of format ``fmt`` (verified, size-bounded)."""
    doc = json.loads(store.get(cid, max_size=max_size))
    if not isinstance(doc, dict) or doc.get("format") != fmt:
        raise ValueError(f"{cid} is not a {fmt} document")
    return doc
