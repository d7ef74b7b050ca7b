"""Off-chain documents the gateway writes to the content store, and their on-chain encodings.

* task spec (``drlaas-task/1``): env spec, observation spec, training budget, seed. Its CID is
  the task's on-chain ``description`` (docs/platform.md, "Task spec"), so anyone can fetch it
  and check it against the chain.
* model bundle (``drlaas-bundle/1``): a small JSON manifest naming the CID and size of each
  file of a shared model (``model.safetensors``, ``model.json``). The MMC stores the manifest's
  CID; the gateway's download endpoint resolves a file through it and streams that file's
  bytes verified block by block against its CID.
* environment attributes (MMC ``env``, Table 5.2): ``ENV_ATTRIBUTES`` of an EnvSpec as
  uint32, the vector the Eq. 13/22 distance compares.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from backend.store import CID, ContentStore, InvalidCID

TASK_SPEC_FORMAT = "drlaas-task/1"
BUNDLE_FORMAT = "drlaas-bundle/1"
MAX_SPEC_BYTES = 64 * 1024
MAX_MANIFEST_BYTES = 64 * 1024
BUNDLE_FILES = ("model.safetensors", "model.json")
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


def canonical_json(doc: dict[str, Any]) -> bytes:
    """Sorted keys, no spaces: equal documents give equal bytes, hence equal CIDs."""
    return json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()


def load_json_doc(store: ContentStore, cid: str, *, max_size: int, fmt: str) -> dict[str, Any]:
    """Fetch a small JSON document of format ``fmt`` (verified, size-bounded)."""
    doc = json.loads(store.get(cid, max_size=max_size))
    if not isinstance(doc, dict) or doc.get("format") != fmt:
        raise ValueError(f"{cid} is not a {fmt} document")
    return doc


def add_bundle(store: ContentStore, files: dict[str, bytes]) -> str:
    """Store each file and a manifest of them; return the manifest's CID (the model's CID)."""
    entries = {}
    for name, data in files.items():
        entries[name] = {"cid": store.add(data), "size": len(data)}
    return store.add(canonical_json({"format": BUNDLE_FORMAT, "files": entries}))


def bundle_entry(store: ContentStore, cid: str, name: str) -> tuple[str, int]:
    """(file CID, size) of ``name`` in the bundle ``cid``; KeyError if the bundle lacks it."""
    doc = load_json_doc(store, cid, max_size=MAX_MANIFEST_BYTES, fmt=BUNDLE_FORMAT)
    files = doc.get("files")
    if not isinstance(files, dict) or name not in files:
        raise KeyError(name)
    entry = files[name]
    file_cid, size = entry.get("cid"), entry.get("size")
    if not isinstance(file_cid, str) or not isinstance(size, int) or size < 0:
        raise ValueError(f"bundle {cid}: bad entry for {name}")
    try:
        CID.parse(file_cid)
    except InvalidCID:
        raise ValueError(f"bundle {cid}: bad CID for {name}") from None
    return file_cid, size
