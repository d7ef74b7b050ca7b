"""One check of a model bundle, run by the gateway on what its content store holds under a CID
before it lists the bundle on the MMC (``POST /models``) or accepts it as a task's expert or
walls CAE (``backend.api.experts``): what passes here is what the workers load
(``workers.daemon.experts``, which fetches and checks the bundle again on its side), so a buyer
never pays for, and a worker never accepts an offer naming, a model no worker can use.

A model bundle (``backend.store.bundle``: a ``drlaas-bundle/1`` manifest) holds exactly
``model.safetensors`` and ``model.json`` (``MODEL_FILES``, written by ``upload_model``):

* every file name is plain (no path separator, no ``..``) and the set is exactly those two;
* the card is a JSON object of at most :data:`MAX_CARD_BYTES` whose ``format`` is the one
  ``workers.mdrl.modelio.save_model`` writes (``drlaas-model/1``);
* the weights are at most :data:`MAX_WEIGHTS_BYTES` (and the store's bound), declared in the
  manifest and checked before a byte is fetched, and the fetched file has that size;
* the weights are a safetensors file a worker loads (``workers.mdrl.weightsfile``, the check
  the workers run: the header length, pickles and zip archives refused by name and never
  parsed, the ``safetensors`` library's check of every tensor's byte range, at least one
  tensor, none empty, dtypes the workers load), checked from a temporary file; and when the
  card lists its tensors (``architecture.tensors``, as ``save_model`` writes), the file's
  tensors (a walls encoder's ``walls_encoder.*`` aside) are exactly those, with those shapes.

A refusal is a :class:`BundleRefused` naming a rule and what is wrong; store errors
(``NotFound`` of the manifest, ``CIDMismatch``, ``StoreUnavailable``) propagate for the caller
to answer as it does for any read of the store.
"""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from backend.store import ContentStore, ContentTooLarge, InvalidContent, NotFound
from backend.store.bundle import MAX_CARD_BYTES, MODEL_FILES, read_bundle
from workers.mdrl.modelio import CARD, CARD_FORMAT, ENCODER_PREFIX, WEIGHTS
from workers.mdrl.weightsfile import (
    MAX_WEIGHTS_BYTES,
    Tensors,
    WeightsFileError,
    check_head,
    check_weights_file,
)


class BundleRefused(ValueError):
    """A bundle that is not a usable model: ``rule`` names the check, ``msg`` what is wrong."""

    def __init__(self, rule: str, msg: str) -> None:
        super().__init__(msg)
        self.rule, self.msg = rule, msg


@dataclass(frozen=True)
class ModelBundle:
    """A bundle that passed :func:`check_model_bundle`."""

    files: dict[str, tuple[str, int]]
    """{name: (file CID, size)} of the manifest."""
    card: dict[str, Any]
    tensors: Tensors
    """{name: (dtype, shape)} of the weights' header."""


def check_model_bundle(
    store: ContentStore, cid: str, *, max_weights: int = MAX_WEIGHTS_BYTES
) -> ModelBundle:
    """The bundle ``cid`` once it is a usable model (see the module); :class:`BundleRefused`
    otherwise. Fetches the card and the weights, each verified against its CID and bounded by
    its manifest size (the weights to a temporary file)."""
    try:
        files = read_bundle(store, cid)
    except (InvalidContent, ContentTooLarge) as exc:
        raise BundleRefused("bundle_invalid", f"{cid} is not a bundle manifest: {exc}") from None
    check_file_set(files)
    card = _read_card(store, *files[CARD])
    bound = min(max_weights, store.max_size)
    tensors = _read_weights(store, *files[WEIGHTS], bound)
    check_tensors_match_card(tensors, card)
    return ModelBundle(files=files, card=card, tensors=tensors)


def check_file_set(files: dict[str, Any]) -> None:
    """Plain names (``bundle_file_name_invalid``), exactly ``MODEL_FILES``
    (``bundle_files_invalid``)."""
    for name in files:
        if not plain_name(name):
            raise BundleRefused(
                "bundle_file_name_invalid",
                f"the manifest names a file {name!r}: a bundle's file names are plain "
                "(no path separator, no '..', no control character)",
            )
    if sorted(files) != sorted(MODEL_FILES):
        extra = sorted(set(files) - set(MODEL_FILES))
        missing = sorted(set(MODEL_FILES) - set(files))
        what = "; ".join(
            part
            for part in (
                f"unexpected {extra}" if extra else "",
                f"missing {missing}" if missing else "",
            )
            if part
        )
        raise BundleRefused(
            "bundle_files_invalid",
            f"a model bundle holds exactly {list(MODEL_FILES)} (weights as safetensors + "
            f"card), this one holds {sorted(files)} ({what})",
        )


def plain_name(name: Any) -> bool:
    """A file name that is one path component: not empty, not ``.``/``..``, no separator."""
    return (
        isinstance(name, str)
        and 0 < len(name) <= 255
        and name not in (".", "..")
        and "/" not in name
        and "\\" not in name
        and not any(ord(c) < 32 or ord(c) == 127 for c in name)
    )


def _fetch_error(name: str, file_cid: str, exc: Exception) -> BundleRefused:
    if isinstance(exc, NotFound):
        return BundleRefused(
            "bundle_file_not_found", f"the content store does not hold its {name} ({file_cid})"
        )
    return BundleRefused(  # ContentTooLarge: more bytes than the manifest declares
        "bundle_size_mismatch", f"{name} ({file_cid}) is larger than its manifest says: {exc}"
    )


def _read_card(store: ContentStore, file_cid: str, size: int) -> dict[str, Any]:
    if size > MAX_CARD_BYTES:
        raise BundleRefused(
            "card_invalid", f"{CARD} is {size} bytes, the bound is {MAX_CARD_BYTES}"
        )
    try:
        raw = store.get(file_cid, max_size=max(size, 1))
    except (NotFound, ContentTooLarge) as exc:
        raise _fetch_error(CARD, file_cid, exc) from None
    if len(raw) != size:
        raise BundleRefused(
            "bundle_size_mismatch", f"{CARD} has {len(raw)} bytes, its manifest says {size}"
        )
    try:
        card = json.loads(raw)  # bounded by MAX_CARD_BYTES; too deep is a RecursionError
    except (ValueError, RecursionError) as exc:
        raise BundleRefused("card_invalid", f"{CARD} (its card) is not JSON: {exc}") from None
    if not isinstance(card, dict):
        raise BundleRefused("card_invalid", f"{CARD} (its card) is not a JSON object")
    if card.get("format") != CARD_FORMAT:
        raise BundleRefused(
            "card_format_invalid",
            f"{CARD} has format {card.get('format')!r}: a model's card is {CARD_FORMAT!r}",
        )
    return card


def _read_weights(store: ContentStore, file_cid: str, size: int, bound: int) -> Tensors:
    if size == 0:
        raise BundleRefused("weights_empty", f"{WEIGHTS} is empty (0 bytes)")
    if size > bound:
        raise BundleRefused(
            "weights_too_large", f"{WEIGHTS} is {size} bytes, more than the bound of {bound}"
        )
    with tempfile.TemporaryDirectory(prefix="drlaas-bundle-") as tmp:
        path = Path(tmp) / WEIGHTS
        head, got = b"", 0
        try:
            with path.open("wb") as out:
                for chunk in store.iter_get(file_cid, max_size=size):  # each block verified
                    if len(head) < 8:
                        head += chunk[: 8 - len(head)]
                        if len(head) == 8:
                            _refuse_bad(check_head, head, size)  # before the rest is fetched
                    out.write(chunk)
                    got += len(chunk)
        except (NotFound, ContentTooLarge) as exc:
            raise _fetch_error(WEIGHTS, file_cid, exc) from None
        if got != size:
            raise BundleRefused(
                "bundle_size_mismatch", f"{WEIGHTS} has {got} bytes, its manifest says {size}"
            )
        _refuse_bad(check_head, head, size)
        return _refuse_bad(check_weights_file, path)


def _refuse_bad(check: Any, *args: Any) -> Any:
    """A ``workers.mdrl.weightsfile`` check, its refusal as a :class:`BundleRefused`."""
    try:
        return check(*args)
    except WeightsFileError as exc:
        raise BundleRefused(exc.rule, str(exc)) from None


def check_tensors_match_card(tensors: Tensors, card: dict[str, Any]) -> None:
    """When the card lists its tensors (``architecture.tensors``: {name: shape}, as
    ``save_model`` writes), the weights hold exactly those (a walls encoder's aside), with
    those shapes (``weights_mismatch_card``)."""
    arch = card.get("architecture")
    declared = arch.get("tensors") if isinstance(arch, dict) else None
    if declared is None:
        return
    if not isinstance(declared, dict):
        raise BundleRefused("card_invalid", f"{CARD}: architecture.tensors is not an object")
    ours = {k: list(s) for k, (_, s) in tensors.items() if not k.startswith(ENCODER_PREFIX)}
    for name in sorted(set(declared) | set(ours)):
        if name not in ours:
            problem = "is not in the weights"
        elif name not in declared:
            problem = "is in the weights but not on the card"
        elif declared[name] != ours[name]:
            problem = f"has shape {ours[name]}, the card says {declared[name]!r}"
        else:
            continue
        raise BundleRefused(
            "weights_mismatch_card",
            f"{WEIGHTS} does not match the card's architecture: tensor {name!r} {problem}",
        )
