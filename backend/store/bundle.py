"""A model in the content store: each file added on its own, plus a manifest naming them.

``{"format": "drlaas-bundle/1", "files": {name: {"cid": ..., "size": ...}}}`` in canonical JSON;
the manifest's CID is what the chain stores (TMC outcome, MMC model). Readers resolve a file
through the manifest and fetch it verified against its own CID, bounded by its declared size.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from workers.mdrl.weightsfile import MAX_WEIGHTS_BYTES

from .cid import CID
from .errors import InvalidCID, InvalidContent

BUNDLE_FORMAT = "drlaas-bundle/1"
MODEL_FILES = ("model.safetensors", "model.json")
MAX_MANIFEST_BYTES = 64 * 1024
MAX_CARD_BYTES = 1 << 20
"""Bound on a model card (``model.json``) wherever one is read: gateway, indexer, worker."""
MAX_MODEL_FILE_BYTES = {"model.safetensors": MAX_WEIGHTS_BYTES, "model.json": MAX_CARD_BYTES}
"""Largest model files a reader writes to disk: a manifest may declare any size, and a store
that keeps identical blocks once holds 256 MiB of zeros in a few hundred kB, so a bound on what
the store holds bounds nothing on the reader's disk."""


def canonical_json(doc: dict[str, Any]) -> bytes:
    """Sorted keys, no spaces: equal documents give equal bytes, hence equal CIDs."""
    return json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()


def add_bundle(store: Any, files: dict[str, bytes]) -> str:
    """Store each file and a manifest of them; return the manifest's CID."""
    entries = {name: {"cid": store.add(data), "size": len(data)} for name, data in files.items()}
    return store.add(canonical_json({"format": BUNDLE_FORMAT, "files": entries}))


def manifest_document(store: Any, cid: str) -> dict[str, Any]:
    """The manifest of bundle ``cid`` as a JSON object of format :data:`BUNDLE_FORMAT`
    (verified, at most :data:`MAX_MANIFEST_BYTES`); InvalidContent otherwise."""
    raw = store.get(cid, max_size=MAX_MANIFEST_BYTES)
    try:
        doc = json.loads(raw)
    except (ValueError, RecursionError):  # RecursionError: nested past the parser's depth
        raise InvalidContent(f"{cid} is not a JSON bundle manifest") from None
    if not isinstance(doc, dict) or doc.get("format") != BUNDLE_FORMAT:
        raise InvalidContent(f"{cid} is not a {BUNDLE_FORMAT} manifest")
    return doc


def read_bundle(store: Any, cid: str) -> dict[str, tuple[str, int]]:
    """{name: (file CID, size)} of the bundle ``cid`` (manifest verified and checked)."""
    doc = manifest_document(store, cid)
    files = doc.get("files")
    if not isinstance(files, dict) or not files:
        raise InvalidContent(f"bundle {cid}: 'files' must be a non-empty object")
    out = {}
    for name, entry in files.items():
        file_cid = entry.get("cid") if isinstance(entry, dict) else None
        size = entry.get("size") if isinstance(entry, dict) else None
        if (not isinstance(file_cid, str) or not isinstance(size, int)
                or isinstance(size, bool) or size < 0):
            raise InvalidContent(f"bundle {cid}: bad entry for {name!r}")
        try:
            CID.parse(file_cid)
        except InvalidCID:
            raise InvalidContent(f"bundle {cid}: bad CID for {name!r}") from None
        out[name] = (file_cid, size)
    return out


def bundle_entry(store: Any, cid: str, name: str) -> tuple[str, int]:
    """(file CID, size) of ``name`` in the bundle ``cid``; KeyError if the bundle lacks it."""
    return read_bundle(store, cid)[name]


def upload_model(store: Any, model_dir: str | os.PathLike[str]) -> str:
    """Add ``model.safetensors`` and ``model.json`` of ``model_dir`` as a bundle; its CID."""
    d = Path(model_dir)
    missing = [n for n in MODEL_FILES if not (d / n).is_file()]
    if missing:
        raise FileNotFoundError(f"model directory {d} lacks {missing}")
    return add_bundle(store, {name: (d / name).read_bytes() for name in MODEL_FILES})


def model_files(store: Any, cid: str) -> dict[str, tuple[str, int]]:
    """{name: (file CID, size)} of model bundle ``cid``: exactly MODEL_FILES, each declared
    within MAX_MODEL_FILE_BYTES (InvalidContent naming the file otherwise)."""
    files = read_bundle(store, cid)
    if sorted(files) != sorted(MODEL_FILES):
        raise InvalidContent(
            f"bundle {cid} must hold exactly {list(MODEL_FILES)}, has {sorted(files)}"
        )
    for name, (_, size) in files.items():
        if size > MAX_MODEL_FILE_BYTES[name]:
            raise InvalidContent(
                f"{name} of bundle {cid} declares {size} bytes, more than the "
                f"{MAX_MODEL_FILE_BYTES[name]} a model's {name} may have"
            )
    return files


def check_model_card(store: Any, cid: str, files: dict[str, tuple[str, int]]) -> None:
    """Fetch and check the card of model bundle ``cid`` before a file is written: a JSON
    object, and a policy's card within the task-spec bounds
    (``workers.mdrl.modelio.check_card_bounds``: an ``eval`` of a card saying
    ``max_steps: 1e9`` would never end). InvalidContent names what is wrong. A walls CAE's
    card (``kind``) is checked when it is loaded."""
    from workers.mdrl.modelio import CARD_FORMAT, check_card_bounds

    card_cid, size = files["model.json"]
    raw = store.get(card_cid, max_size=max(size, 1))
    try:
        card = json.loads(raw)
    except (ValueError, RecursionError):
        raise InvalidContent(f"model.json of bundle {cid} is not JSON") from None
    if not isinstance(card, dict):
        raise InvalidContent(f"model.json of bundle {cid} is not a JSON object")
    if card.get("format") != CARD_FORMAT or "kind" in card:
        return
    try:
        if not isinstance(card.get("env"), dict) or not isinstance(card.get("observation"), dict):
            raise ValueError("the card needs 'env' and 'observation' objects")
        check_card_bounds(card, task_grid=False)
    except (KeyError, TypeError, ValueError, ArithmeticError) as exc:
        raise InvalidContent(f"model.json of bundle {cid}: {exc} (bounds of a task spec)") from None


def pull_model(store: Any, cid: str, dest: str | os.PathLike[str]) -> Path:
    """Fetch both model files of bundle ``cid`` into ``dest``, each verified by its CID and
    bounded (``model_files``), once its card is checked (``check_model_card``)."""
    files = model_files(store, cid)
    check_model_card(store, cid, files)
    out = Path(dest)
    out.mkdir(parents=True, exist_ok=True)
    for name in MODEL_FILES:
        fetch_model_file(store, cid, name, files[name], out / name)
    return out


def fetch_model_file(
    store: Any, cid: str, name: str, entry: tuple[str, int], path: str | os.PathLike[str]
) -> None:
    """Write file ``name`` of bundle ``cid`` (its manifest ``entry``: file CID, size) to
    ``path``, verified against its CID and of exactly the size the manifest declares:
    InvalidContent naming it otherwise, and nothing left at ``path`` (a manifest saying
    5,000 bytes of a 3,000-byte file was written as it was)."""
    file_cid, size = entry
    got = store.get_to_file(file_cid, path, max_size=max(size, 1))
    if got != size:
        Path(path).unlink(missing_ok=True)
        raise InvalidContent(f"{name} of bundle {cid} has {got} bytes, its manifest says {size}")
