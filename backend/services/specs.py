"""Off-chain documents the gateway writes to the content store, and their on-chain encodings.

* task spec (``drlaas-task/1``): env spec, observation spec, training budget, seed. Its CID is
  the task's on-chain ``description`` (docs/platform.md, "Task spec"), so anyone can fetch it
  and check it against the chain.
* model bundle: see ``backend.store.bundle`` (the MMC stores the manifest's CID; the download
  endpoint resolves a file through it and streams its bytes verified against its own CID).
* environment attributes (MMC ``env``, Table 5.2): ``ENV_ATTRIBUTES`` of an EnvSpec as
  uint32, the vector the Eq. 13/22 distance compares.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from backend.store import ContentStore

TASK_SPEC_FORMAT = "drlaas-task/1"
MAX_SPEC_BYTES = 64 * 1024
ENV_ATTRIBUTES = ("rows", "cols", "agents", "moves", "walls_min", "walls_max")
"""Order of the on-chain env attribute vector (uint32 each)."""

# Gateway policy bounds on what a task may ask for (the MDRL core accepts more, but a public
# endpoint must not let one request book a worker for a year).
ENV_BOUNDS = {"rows": (2, 64), "cols": (2, 64), "agents": (1, 16), "max_steps": (1, 10_000)}


class SpecError(ValueError):
    """A bad document field: ``field`` names it (dotted path), the message says why."""

    def __init__(self, field: str, msg: str) -> None:
        super().__init__(f"{field}: {msg}")
        self.field = field
        self.msg = msg


def validate_env(env: dict[str, Any]) -> Any:
    """``EnvSpec.from_dict`` with the gateway's bounds; :class:`SpecError` naming the field.

    EnvSpec reports all its problems in one message; the first known field name in it is the
    one named (unknown fields are named directly)."""
    from workers.mdrl.spec import EnvSpec

    known = list(EnvSpec.__dataclass_fields__)
    unknown = sorted(set(env) - set(known))
    if unknown:
        raise SpecError(unknown[0], f"unknown environment field (known: {known})")
    for name, (lo, hi) in ENV_BOUNDS.items():
        if name in env:
            v = env[name]
            if isinstance(v, bool) or not isinstance(v, int):
                raise SpecError(name, f"must be an integer, got {v!r}")
            if not lo <= v <= hi:
                raise SpecError(name, f"must be in [{lo}, {hi}], got {v}")
    try:
        spec = EnvSpec.from_dict(env)
    except (ValueError, TypeError, KeyError) as exc:
        text = str(exc)
        field = _first_field(text, known)
        raise SpecError(field or "env", text) from None
    if spec.walls[1] > max(spec.rows, spec.cols):
        raise SpecError("walls", f"at most {max(spec.rows, spec.cols)} walls, got {spec.walls}")
    return spec


def _first_field(text: str, names: list[str]) -> str | None:
    hits = [(text.find(n), n) for n in names if n in text]
    if "grid" in text and not hits:
        return "rows"
    return min(hits)[1] if hits else None


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
