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

A worker fetches a task's models before it accepts the offer, so a requester could make it
download up to 8 x 64 MiB for every offer it then declines. Hence a :class:`ModelCache` shared
by the worker's jobs (``<worker data>/cache/models/<CID v1>/``, least recently used evicted past
its byte bound): bundles whose files were verified against their CIDs, linked into each job
that names them, so a second offer naming the same models downloads nothing (their card and
weights checks are run again on the cached files: cheap, local). :func:`offer_fetch_bytes` sizes
what an offer's check would download from the manifests alone, before any card or weights.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from backend.store import (
    CID,
    ContentStore,
    FindTimeout,
    InvalidCID,
    NotFound,
    StoreError,
    StoreUnavailable,
)
from backend.store.bundle import MAX_CARD_BYTES, MODEL_FILES, fetch_model_file, read_bundle
from workers.mdrl.weightsfile import MAX_WEIGHTS_BYTES, WeightsFileError, check_weights_file

log = logging.getLogger(__name__)

EXPERTS_DIR = "experts"
CAE_DIR = "cae"
#: The worker's model cache, under its data directory (``ModelCache``).
CACHE_DIR = "cache/models"
#: Default bound on the model cache (``DRLAAS_WORKER_MODEL_CACHE_BYTES``): a few offers' worth
#: of the largest experts (8 x 64 MiB each).
DEFAULT_CACHE_BYTES = 2 * 2**30
#: Default bound on the bytes of models (cards and weights, not in the cache) one offer's
#: check may download (``DRLAAS_WORKER_OFFER_FETCH_BYTES``): four of the largest experts.
DEFAULT_OFFER_FETCH_BYTES = 256 * 2**20
#: Store failures worth retrying: the store down, or a node that gave up finding a CID in time
#: (its provider may be offline a while). Not a reason to fail a job or decline an offer.
STORE_OUTAGES = (StoreUnavailable, FindTimeout)

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


class ModelCache:
    """Model bundles whose files were verified against their CIDs and sizes, keyed by the
    bundle's CID v1 (``<root>/<CID>/model.safetensors`` + ``model.json``), shared by the jobs
    of one worker so an offer naming models seen before downloads nothing. What is cached is
    only what the CIDs vouch for: the card and weights checks run again at each use, so a
    bundle that fails them is refused again without a download. Bounded to ``max_bytes`` in
    all, least recently used evicted first (an entry's mtime is its last use); a job links the
    files into its own directory, so evicting an entry never takes a job's files away."""

    def __init__(self, root: str | os.PathLike[str], max_bytes: int = DEFAULT_CACHE_BYTES):
        if max_bytes < 0:
            raise ValueError(f"model cache bound must be >= 0 bytes, got {max_bytes}")
        self.root, self.max_bytes = Path(root), max_bytes

    def get(self, ref: str) -> Path | None:
        """The cached directory of bundle ``ref`` (marked used now), or None."""
        entry = self.root / expert_key(ref)
        if not all((entry / name).is_file() for name in MODEL_FILES):
            return None
        try:
            os.utime(entry)
        except OSError:  # evicted meanwhile
            return None
        return entry

    def add(self, ref: str, files: Path) -> None:
        """Keep the verified files of bundle ``ref`` found in ``files`` (linked, not copied,
        when the file system allows), then evict down to the bound."""
        key = expert_key(ref)
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(dir=self.root, prefix=f".add-{key}."))
        try:
            _link_files(files, tmp)
            if (self.root / key).exists():
                shutil.rmtree(tmp, ignore_errors=True)  # cached by another fetch meanwhile
            else:
                os.replace(tmp, self.root / key)
        except OSError as exc:  # a cache that cannot be written costs downloads, not the job
            shutil.rmtree(tmp, ignore_errors=True)
            log.warning("model cache %s: cannot keep %s: %s", self.root, key, exc)
            return
        self.evict()

    def size(self) -> int:
        """Bytes held by the cached bundles."""
        return sum(size for _, _, size in self._entries())

    def _entries(self) -> list[tuple[int, Path, int]]:
        """(last use, directory, bytes) of each cached bundle, least recently used first."""
        out = []
        if not self.root.is_dir():
            return out
        for entry in self.root.iterdir():
            if entry.name.startswith("."):
                continue
            try:
                used = entry.stat().st_mtime_ns
                size = sum((entry / name).stat().st_size for name in MODEL_FILES)
            except OSError:  # incomplete or being removed: not a cached bundle
                continue
            out.append((used, entry, size))
        return sorted(out, key=lambda e: (e[0], e[1].name))

    def evict(self) -> list[str]:
        """Remove least recently used bundles until the cache holds at most ``max_bytes``, and
        leftovers of adds cut short (over an hour old); the CIDs evicted."""
        entries = self._entries()
        total = sum(size for _, _, size in entries)
        gone = []
        for _, entry, size in entries:
            if total <= self.max_bytes:
                break
            doomed = entry.with_name(f".evict-{entry.name}-{os.getpid()}")
            try:
                os.replace(entry, doomed)  # out of sight at once, removed after
            except OSError:
                continue
            shutil.rmtree(doomed, ignore_errors=True)
            total -= size
            gone.append(entry.name)
        stale = time.time() - 3600
        for left in self.root.glob(".*"):
            try:
                if left.stat().st_mtime < stale:
                    shutil.rmtree(left, ignore_errors=True)
            except OSError:
                continue
        return gone


def _link_files(src: Path, dest: Path) -> None:
    """Hard-link (copy where links fail) the model files of ``src`` into ``dest``: verified
    files are never written again, so a link is as good as a copy."""
    for name in MODEL_FILES:
        (dest / name).unlink(missing_ok=True)
        try:
            os.link(src / name, dest / name)
        except OSError:  # another file system, no hard links
            shutil.copyfile(src / name, dest / name)


def fetch_experts(
    store: ContentStore,
    refs: tuple[str, ...] | list[str],
    job_dir: Path,
    *,
    max_weights: int = MAX_WEIGHTS_BYTES,
    cache: ModelCache | None = None,
) -> dict[str, Path]:
    """{reference as the spec writes it: verified model directory} for every expert."""
    return {
        ref: fetch_expert(store, ref, job_dir, max_weights=max_weights, cache=cache)
        for ref in refs
    }


def fetch_expert(
    store: ContentStore,
    ref: str,
    job_dir: Path,
    *,
    max_weights: int = MAX_WEIGHTS_BYTES,
    cache: ModelCache | None = None,
) -> Path:
    """The verified model directory of expert ``ref`` under ``job_dir/experts`` (fetched once;
    from ``cache`` when it holds the bundle).

    :data:`STORE_OUTAGES` propagate (try again later); every other failure is an
    :class:`ExpertFetchError` naming the CID."""
    return _fetch_verified(
        store, ref, Path(job_dir) / EXPERTS_DIR, max_weights, check_card, cache
    )


def fetch_walls_cae(
    store: ContentStore,
    ref: str,
    job_dir: Path,
    *,
    max_weights: int = MAX_WEIGHTS_BYTES,
    cache: ModelCache | None = None,
) -> Path:
    """The verified walls CAE (Ch. 4, ``observation.walls_embedding``) of a task under
    ``job_dir/cae``: the same checks as an expert's, with a CAE card instead of a policy's."""
    return _fetch_verified(
        store, ref, Path(job_dir) / CAE_DIR, max_weights, check_cae_card, cache
    )


def _fetch_verified(
    store: ContentStore,
    ref: str,
    parent: Path,
    max_weights: int,
    check: Any,
    cache: ModelCache | None = None,
) -> Path:
    key = expert_key(ref)
    final = parent / key
    if all((final / name).is_file() for name in MODEL_FILES):
        return final  # verified before it was renamed into place
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{key}."))
    try:
        cached = cache.get(ref) if cache is not None else None
        if cached is not None:
            _check_cached_sizes(cached, ref, max_weights)
            _link_files(cached, tmp)
        else:
            _download(store, ref, tmp, max_weights)
            if cache is not None:  # verified against the CIDs: worth keeping even if the
                cache.add(ref, tmp)  # checks below fail (refused again without a download)
        check_safetensors(tmp / "model.safetensors", ref)
        check(tmp / "model.json", ref)
        shutil.rmtree(final, ignore_errors=True)  # a half-written leftover of an older layout
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def _check_cached_sizes(entry: Path, ref: str, max_weights: int) -> None:
    """A cached bundle within this worker's bounds (they may be lower than when it was
    cached), with the message a manifest over the bound gets."""
    bounds = {"model.safetensors": max_weights, "model.json": MAX_CARD_BYTES}
    for name in MODEL_FILES:
        size = (entry / name).stat().st_size
        if size > bounds[name]:
            raise ExpertFetchError(
                ref, f"{name} is {size} bytes, more than the bound of {bounds[name]} bytes"
            )


def offer_fetch_bytes(
    store: ContentStore,
    refs: Iterable[str],
    *,
    max_weights: int = MAX_WEIGHTS_BYTES,
    cache: ModelCache | None = None,
) -> int:
    """Bytes (cards and weights) checking an offer naming the models ``refs`` would download:
    those ``cache`` does not hold, sized from their manifests alone (a few hundred bytes each),
    which must name the model files within the bounds. ExpertFetchError names a bundle that
    is unusable on its manifest; nothing else is fetched."""
    total, seen = 0, set()
    for ref in refs:
        key = expert_key(ref)
        if key in seen:
            continue
        seen.add(key)
        if cache is not None and (cached := cache.get(ref)) is not None:
            _check_cached_sizes(cached, ref, max_weights)
            continue
        total += sum(size for _, size in _manifest(store, ref, max_weights).values())
    return total


def check_expert_card(
    store: ContentStore,
    ref: str,
    *,
    max_weights: int = MAX_WEIGHTS_BYTES,
    task: Any = None,
    cache: ModelCache | None = None,
) -> tuple[Any, Any]:
    """The checks of an expert that need only its manifest and card (at most MAX_CARD_BYTES),
    run before a worker accepts an offer: a requester naming a model no worker can use (the
    gateway's bundle check is looser than this), or one that cannot serve the task's EnvSpec
    ``task`` (``experts.expert_misfit``), gets its offers declined, not a worker's job failed
    on chain after acceptance. The weights are fetched and checked after acceptance. Returns
    the expert's (EnvSpec, ObservationSpec): the resource model sizes its nets from them."""
    from workers.mdrl.experts import expert_misfit
    from workers.mdrl.modelio import card_specs

    card = _read_card(store, ref, max_weights, check_card, cache)
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
    cache: ModelCache | None = None,
) -> dict[str, Any]:
    """``check_expert_card`` for a task's walls CAE (``observation.walls_embedding``): its
    manifest and card, and that it reads the task's ``grid`` (rows, cols) into the spec's
    ``embedding`` size (``observation.walls_embedding_size``), before a worker accepts the
    offer."""
    card = _read_card(store, ref, max_weights, check_cae_card, cache)
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


def _read_card(
    store: ContentStore, ref: str, max_weights: int, check: Any, cache: ModelCache | None
) -> dict[str, Any]:
    """The checked card of bundle ``ref``: the cached one, else its manifest and card alone
    fetched (the weights' size bounded on the manifest, none of their bytes fetched)."""
    cached = cache.get(ref) if cache is not None else None
    if cached is not None:
        _check_cached_sizes(cached, ref, max_weights)
        return check(cached / "model.json", ref)  # type: ignore[no-any-return]
    with tempfile.TemporaryDirectory(prefix="drlaas-card-") as tmp:
        _download(store, ref, Path(tmp), max_weights, only=("model.json",))
        return check(Path(tmp) / "model.json", ref)  # type: ignore[no-any-return]


def _manifest(store: ContentStore, ref: str, max_weights: int) -> dict[str, tuple[str, int]]:
    """{file name: (CID, size)} of bundle ``ref``: exactly the model files, each within its
    bound, checked before a byte of them is fetched."""
    bounds = {"model.safetensors": max_weights, "model.json": MAX_CARD_BYTES}
    try:
        files = read_bundle(store, ref)
    except STORE_OUTAGES:
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
    return files


def _download(
    store: ContentStore,
    ref: str,
    dest: Path,
    max_weights: int,
    only: tuple[str, ...] = MODEL_FILES,
) -> None:
    files = _manifest(store, ref, max_weights)
    for name in only:
        file_cid = files[name][0]
        try:  # verified block by block, and of the size the manifest declares
            fetch_model_file(store, ref, name, files[name], dest / name)
        except STORE_OUTAGES:
            raise
        except NotFound:
            raise ExpertFetchError(ref, f"{name} ({file_cid}) is not in the store") from None
        except StoreError as exc:
            raise ExpertFetchError(ref, f"{name} ({file_cid}) failed verification: {exc}") from None


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
    check_card_walls_encoder(card, ref)
    return card


def check_card_walls_encoder(card: dict[str, Any], ref: str) -> None:
    """A policy card's ``walls_encoder`` (a model trained with a walls CAE carries its encoder)
    within the bounds of a walls CAE's card (``cae.check_cae_fields``), on the card alone,
    before any weights are fetched: a 1 MiB card lists ~500,000 conv layers, each built when
    the expert loads (minutes of CPU and GBs of memory per offer before the loader's own
    bound)."""
    from workers.mdrl.cae import check_encoder_fields

    if "walls_encoder" not in card:
        return
    enc = card["walls_encoder"]
    try:
        if not isinstance(enc, dict):
            raise ValueError(f"expected an object, got {type(enc).__name__}")
        check_encoder_fields(enc)
    except ValueError as exc:
        raise ExpertFetchError(ref, f"model.json: walls_encoder: {exc}") from None


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
