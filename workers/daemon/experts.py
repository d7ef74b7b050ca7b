"""Expert models of an MEDC job (thesis Alg. 5.1; platform flow of Ch. 5 and 7.8), and the walls
CAE a Ch. 4 task may name (``observation.walls_embedding``): fetched from the content store by
CID, verified, kept in the job directory.

A task spec names its experts by model CID (``experts``: bundle manifests, as the MMC lists
them). Nothing from the network is trusted, so before an expert guides training here:

* the CID must parse, and the manifest must name exactly ``model.safetensors`` and
  ``model.json`` with sizes within :data:`MAX_WEIGHTS_BYTES` / :data:`MAX_CARD_BYTES` (checked
  before a byte of them is fetched);
* every block is verified against its CID as it arrives (``ContentStore.get_to_file``) and the
  file must have the size the manifest declares;
* the weights must be a loadable safetensors file (``workers.mdrl.weightsfile``, the check
  the gateway runs too: a pickle or a zip archive, e.g. a ``torch.save`` file, is refused and
  never unpickled);
* the card must be a ``drlaas-model/1`` card whose env and observation this code can rebuild.

A verified expert lives in ``<job>/experts/<CID v1>/`` (a CAE in ``<job>/cae/<CID v1>/``),
renamed into place only once complete, so a restarted job resumes with the same files and never
fetches them again.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from backend.store import (
    CID,
    ContentStore,
    InvalidCID,
    NotFound,
    StoreError,
    StoreUnavailable,
)
from backend.store.bundle import MAX_CARD_BYTES, MODEL_FILES, read_bundle
from workers.mdrl.weightsfile import MAX_WEIGHTS_BYTES, WeightsFileError, check_weights_file

EXPERTS_DIR = "experts"
CAE_DIR = "cae"

class ExpertFetchError(ValueError):
    """An expert CID that cannot be used: the message names the CID and what is wrong."""

    def __init__(self, cid: str, reason: str):
        super().__init__(f"expert {cid}: {reason}")
        self.cid, self.reason = cid, reason


def expert_key(ref: str) -> str:
    """The canonical CIDv1 text of an expert reference; ExpertFetchError if it is not a CID
    (a platform task cannot name a path on the worker's disk nor a built-in)."""
    try:
        return str(CID.parse(ref).v1())
    except (InvalidCID, ValueError):
        raise ExpertFetchError(
            ref, "not a model CID (a platform task names its experts by the CID of their bundle)"
        ) from None


def fetch_experts(
    store: ContentStore,
    refs: tuple[str, ...] | list[str],
    job_dir: Path,
    *,
    max_weights: int = MAX_WEIGHTS_BYTES,
) -> dict[str, Path]:
    """{reference as the spec writes it: verified model directory} for every expert."""
    return {ref: fetch_expert(store, ref, job_dir, max_weights=max_weights) for ref in refs}


def fetch_expert(
    store: ContentStore, ref: str, job_dir: Path, *, max_weights: int = MAX_WEIGHTS_BYTES
) -> Path:
    """The verified model directory of expert ``ref`` under ``job_dir/experts`` (fetched once).

    :class:`StoreUnavailable` propagates (try again later); every other failure is an
    :class:`ExpertFetchError` naming the CID."""
    return _fetch_verified(store, ref, Path(job_dir) / EXPERTS_DIR, max_weights, check_card)


def fetch_walls_cae(
    store: ContentStore, ref: str, job_dir: Path, *, max_weights: int = MAX_WEIGHTS_BYTES
) -> Path:
    """The verified walls CAE (Ch. 4, ``observation.walls_embedding``) of a task under
    ``job_dir/cae``: the same checks as an expert's, with a CAE card instead of a policy's."""
    return _fetch_verified(store, ref, Path(job_dir) / CAE_DIR, max_weights, check_cae_card)


def _fetch_verified(
    store: ContentStore, ref: str, parent: Path, max_weights: int, check: Any
) -> Path:
    key = expert_key(ref)
    final = parent / key
    if all((final / name).is_file() for name in MODEL_FILES):
        return final  # verified before it was renamed into place
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{key}."))
    try:
        _download(store, ref, tmp, max_weights)
        check_safetensors(tmp / "model.safetensors", ref)
        check(tmp / "model.json", ref)
        shutil.rmtree(final, ignore_errors=True)  # a half-written leftover of an older layout
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def check_expert_card(
    store: ContentStore, ref: str, *, max_weights: int = MAX_WEIGHTS_BYTES, task: Any = None
) -> tuple[Any, Any]:
    """The checks of an expert that need only its manifest and card (at most MAX_CARD_BYTES),
    run before a worker accepts an offer: a requester naming a model no worker can use (the
    gateway's bundle check is looser than this), or one that cannot serve the task's EnvSpec
    ``task`` (``experts.expert_misfit``), gets its offers declined, not a worker's job failed
    on chain after acceptance. The weights are fetched and checked after acceptance. Returns
    the expert's (EnvSpec, ObservationSpec): the resource model sizes its nets from them."""
    from workers.mdrl.experts import expert_misfit
    from workers.mdrl.modelio import card_specs

    with tempfile.TemporaryDirectory(prefix="drlaas-card-") as tmp:
        _download(store, ref, Path(tmp), max_weights, only=("model.json",))
        card = check_card(Path(tmp) / "model.json", ref)
    try:
        env, obs = card_specs(card)
    except (ValueError, TypeError, KeyError) as exc:  # SpecError is a ValueError
        raise ExpertFetchError(ref, f"model.json: {exc}") from None
    if task is not None:
        why = expert_misfit(env, obs.kind, bool(obs.walls_embedding), task)
        if why is not None:
            raise ExpertFetchError(ref, f"this expert cannot serve the task: {why}")
    return env, obs


def check_walls_cae_card(
    store: ContentStore,
    ref: str,
    *,
    max_weights: int = MAX_WEIGHTS_BYTES,
    grid: tuple[int, int] | None = None,
    embedding: int | None = None,
) -> dict[str, Any]:
    """``check_expert_card`` for a task's walls CAE (``observation.walls_embedding``): its
    manifest and card, and that it reads the task's ``grid`` (rows, cols) into the spec's
    ``embedding`` size (``observation.walls_embedding_size``), before a worker accepts the
    offer."""
    with tempfile.TemporaryDirectory(prefix="drlaas-card-") as tmp:
        _download(store, ref, Path(tmp), max_weights, only=("model.json",))
        card = check_cae_card(Path(tmp) / "model.json", ref)
    if grid is not None and tuple(card["grid"]) != tuple(grid):
        rows, cols = card["grid"]
        raise ExpertFetchError(
            ref, f"this walls CAE reads {rows}x{cols} maps; the task's grid is "
            f"{grid[0]}x{grid[1]}"
        )
    if embedding is not None and card["embedding"] != embedding:
        raise ExpertFetchError(
            ref, f"this walls CAE has d = {card['embedding']}; the task's spec says "
            f"observation.walls_embedding_size = {embedding}"
        )
    return card


def _download(
    store: ContentStore,
    ref: str,
    dest: Path,
    max_weights: int,
    only: tuple[str, ...] = MODEL_FILES,
) -> None:
    bounds = {"model.safetensors": max_weights, "model.json": MAX_CARD_BYTES}
    try:
        files = read_bundle(store, ref)
    except StoreUnavailable:
        raise
    except StoreError as exc:  # not found, mismatch, not a manifest, too large
        raise ExpertFetchError(ref, f"cannot read its bundle manifest: {exc}") from None
    if sorted(files) != sorted(MODEL_FILES):
        raise ExpertFetchError(
            ref,
            f"the bundle must hold exactly {list(MODEL_FILES)} (weights "
            f"as safetensors + card), it holds {sorted(files)}",
        )
    for name in MODEL_FILES:
        file_cid, size = files[name]
        if size > bounds[name]:
            raise ExpertFetchError(
                ref, f"{name} is {size} bytes, more than the bound of {bounds[name]} bytes"
            )
    for name in only:
        file_cid, size = files[name]
        try:
            got = store.get_to_file(file_cid, dest / name, max_size=max(size, 1))
        except StoreUnavailable:
            raise
        except NotFound:
            raise ExpertFetchError(ref, f"{name} ({file_cid}) is not in the store") from None
        except StoreError as exc:
            raise ExpertFetchError(ref, f"{name} ({file_cid}) failed verification: {exc}") from None
        if got != size:
            raise ExpertFetchError(ref, f"{name} has {got} bytes, its manifest says {size}")


def check_safetensors(path: Path, ref: str) -> None:
    """A loadable safetensors file (``workers.mdrl.weightsfile``: header length, pickles and
    archives refused by name, the library's check of every tensor's byte range)."""
    try:
        check_weights_file(path)
    except WeightsFileError as exc:
        raise ExpertFetchError(ref, str(exc)) from None


def check_card(path: Path, ref: str) -> dict[str, Any]:
    """The expert's card, if it is one this worker can rebuild a model from."""
    from workers.mdrl.modelio import CARD_FORMAT, check_card_bounds
    from workers.mdrl.specfields import SpecError

    try:
        card = json.loads(path.read_bytes())
    except (ValueError, RecursionError):
        raise ExpertFetchError(ref, "model.json (its card) is not JSON") from None
    if not isinstance(card, dict) or card.get("format") != CARD_FORMAT:
        got = card.get("format") if isinstance(card, dict) else type(card).__name__
        raise ExpertFetchError(ref, f"model.json is not a {CARD_FORMAT} card (format {got!r})")
    try:
        # The task-spec bounds (grid, agents, window, ...): a card is as untrusted as a spec, and
        # an unbounded one (a 10^5 x 10^5 grid, a window of 10^4) would exhaust the worker's
        # memory when the expert's observer is built.
        check_card_bounds(card)
    except SpecError as exc:
        raise ExpertFetchError(ref, f"model.json: {exc} (bounds of a task spec)") from None
    except (KeyError, TypeError, ValueError, AttributeError, ArithmeticError) as exc:
        raise ExpertFetchError(
            ref,
            f"model.json: its env/observation cannot be rebuilt here ({type(exc).__name__}: {exc})",
        ) from None
    return card


def check_cae_card(path: Path, ref: str) -> dict[str, Any]:
    """The card of a walls CAE (``cae.save_cae``) with the fields its encoder is rebuilt from."""
    from workers.mdrl.cae import CARD, check_cae_fields, load_cae_card

    try:
        card = load_cae_card(path.parent)
        if path.name != CARD:
            raise ValueError(f"expected {CARD}")
        check_cae_fields(card)
    except (KeyError, TypeError, ValueError, RecursionError) as exc:
        raise ExpertFetchError(ref, f"model.json is not a walls CAE card ({exc})") from None
    return card


def load_walls_encoder(ref: str, directory: Path) -> Any:
    """The frozen encoder (``cae.WallsEmbedder``) of a verified CAE directory, named by its
    CID: the trained model's card then records the CID, not this worker's path."""
    from workers.mdrl.cae import WallsEmbedder, load_cae

    try:
        return WallsEmbedder(load_cae(directory).encoder, ref)
    except Exception as exc:  # noqa: BLE001 - weights that do not fit their card
        why = _named_by_cid(exc, directory, ref)
        raise ExpertFetchError(ref, f"cannot load the walls CAE: {why}") from None


def _named_by_cid(exc: Exception, directory: Path, ref: str) -> str:
    """``exc``'s message with this worker's path of the model replaced by the model's CID:
    a reason goes to the requester, who needs the model named, not the worker's disk."""
    return str(exc).replace(str(directory), ref)


def load_job_experts(
    refs: tuple[str, ...], dirs: dict[str, Path], task: Any, seed: int
) -> list[Any]:
    """The experts of a job, each named by its CID (what the outcome's card lists) while its
    weights come from its verified directory; the i-th is seeded ``seed + i`` as
    ``experts.load_experts`` does."""
    from workers.mdrl.experts import load_expert_at

    experts = []
    for i, ref in enumerate(refs):
        try:
            experts.append(load_expert_at(ref, dirs[ref], task, seed + i))
        except Exception as exc:  # noqa: BLE001 - a model that cannot serve the task
            why = _named_by_cid(exc, dirs[ref], ref)
            raise ExpertFetchError(ref, f"cannot guide this task: {why}") from None
    return experts
