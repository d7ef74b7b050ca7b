"""Shared models: search, detail (card + metrics from the bundle), verified download, share
(MMC.addModel), model-sharing requests (MMC.allocateModel) and their reviews; and the
download of a task's outcome by its requester before anyone shares it.

Sharing checks provenance twice: the MMC refuses another worker's outcome, a pending or
rejected outcome and a CID listed before (docs/platform.md, "Sharing a model"); the gateway
first checks what the chain cannot read, that the declared environment is the one on the
model's own card (model.json of the bundle, fetched verified and size-bounded), and that the
bundle is a model the workers can use (``backend.api.bundles.check_model_bundle``: its file
set, the card's format, safetensors weights within bounds), as it checks a task's experts."""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import Iterator
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Path, Query, Request, status
from fastapi.responses import JSONResponse, Response, StreamingResponse
from sqlalchemy import func, or_, select

from backend.api.bundles import BundleRefused, check_model_bundle
from backend.api.cards import read_card
from backend.api.client_key import client_key
from backend.api.conditional import none_match, not_modified
from backend.api.deps import ChainDep, CurrentUser, IndexerDep, SessionDep, SettingsDep, StoreDep
from backend.api.errors import RuleError, rule_responses
from backend.api.head import HEAD_ONLY
from backend.api.pagecache import cached_page
from backend.api.schemas import Address, FractionQuery
from backend.api.slots import ClientSlots
from backend.api.writes import catch_up, field_error, receipt_public
from backend.chain.platform import Metric, Verdict, cid_commitment, cid_hash
from backend.chain.qos import mmc_reputation_fixed
from backend.db import models as m
from backend.schemas.cards import MAX_EXPERTS, CardView, ExpertUsagePublic, is_cid
from backend.schemas.common import (
    ID_DIGITS,
    MAX_DOMAIN,
    MAX_ID,
    TxPublic,
    from_fixed,
    to_fixed,
    wei_to_eth,
)
from backend.schemas.models import (
    AllocatedModelPublic,
    AllocationDetailPublic,
    AllocationModelPublic,
    AllocationsPublic,
    CommitmentCreate,
    CommitmentPublic,
    ExpertPublic,
    ModelAllocationPublic,
    ModelCreate,
    ModelDetailPublic,
    ModelPublic,
    ModelRequestCreate,
    ModelRequestPublic,
    ModelReviewCreate,
    ModelsPublic,
    ProducedByPublic,
)
from backend.services.chain import ChainService
from backend.services.specs import SpecError, env_attributes, validate_env
from backend.store import (
    CIDMismatch,
    ContentTooLarge,
    InvalidContent,
    NotFound,
    StoreError,
    StoreUnavailable,
)
from backend.store.bundle import MAX_CARD_BYTES, bundle_entry, read_bundle
from backend.store.sealed import sealed_envelopes

router = APIRouter(prefix="/models", tags=["models"])
log = logging.getLogger(__name__)
ModelId = Annotated[int, Path(ge=1, le=MAX_ID), ID_DIGITS]
AllocId = Annotated[int, Path(ge=1, le=MAX_ID), ID_DIGITS]
TaskId = Annotated[int, Path(ge=1, le=MAX_ID), ID_DIGITS]
BundleFile = Literal["model.safetensors", "model.json"]
HALF = 500_000
MAX_REQUESTS_SHOWN = 20
NOT_MODIFIED_DOC = "If-None-Match names the file's ETag (its CID): not sent again"

_LIST_COLUMNS = (
    m.ModelRow.id,
    m.ModelRow.cid,
    m.ModelRow.owner,
    m.ModelRow.domain,
    m.ModelRow.env,
    m.ModelRow.agents,
    m.ModelRow.walls_min,
    m.ModelRow.walls_max,
    m.ModelRow.reputation,
    m.ModelRow.alloc_count,
)
_SORT = {
    "reputation": (m.ModelRow.reputation.desc(), m.ModelRow.id),
    "newest": (m.ModelRow.id.desc(),),
    "allocations": (m.ModelRow.alloc_count.desc(), m.ModelRow.id),
}


def _env_spec(env: dict[str, Any], loc: tuple[str, ...]) -> Any:
    try:
        return validate_env(env)
    except SpecError as exc:
        field_error((*loc, exc.field), exc.msg)
        raise  # unreachable: field_error raises


def _env_attrs(env: dict[str, Any], loc: tuple[str, ...]) -> list[int]:
    return env_attributes(_env_spec(env, loc))


def _check_published(store: StoreDep, cid: str) -> None:
    """409 ``model_weights_sealed`` when a file of bundle ``cid`` is sealed to a requester
    (``backend.store.sealed``) and its plaintext is not in the store: a listed model must be
    fetchable by whoever is allocated it, so its owner publishes the files first."""
    try:
        sealed = sealed_envelopes(store, cid)
        files = read_bundle(store, cid)
    except (ValueError, StoreError) as exc:
        field_error(("body", "cid"), f"the bundle is unusable: {exc}", "card_invalid")
    for name in sealed:
        if name in files and not store.has(files[name][0]):
            raise RuleError(
                409,
                "model_weights_sealed",
                f"{name} of {cid} is sealed to its task's requester and not published: the "
                "worker shares it with `drlaas worker share TASK_ID`, which uploads the files",
            )


def _check_bundle(store: StoreDep, cid: str) -> None:
    """422 at ``body.cid`` unless bundle ``cid`` is a model the workers can use
    (``check_model_bundle``): ``type`` names the rule that failed (``bundle_files_invalid``,
    ``bundle_file_name_invalid``, ``card_format_invalid``, ``weights_not_safetensors``,
    ``weights_empty``, ``weights_too_large``, ``weights_mismatch_card``, ...) and ``msg``
    what is wrong; 502 when the store's bytes fail verification, 503 while it is down."""
    try:
        check_model_bundle(store, cid)
    except BundleRefused as exc:
        field_error(("body", "cid"), f"{cid} is not a usable model: {exc.msg}", exc.rule)
    except NotFound:
        field_error(
            ("body", "cid"),
            f"the content store does not hold {cid}: upload the bundle first",
            "bundle_not_found",
        )
    except CIDMismatch as exc:
        raise RuleError(502, "content_corrupt", f"{cid} failed verification: {exc}") from None
    except StoreUnavailable as exc:
        raise RuleError(
            503, "store_unavailable", f"content store: {exc}", headers={"Retry-After": "5"}
        ) from None
    except StoreError as exc:
        field_error(("body", "cid"), f"the bundle is unusable: {exc}", "bundle_invalid")


def _check_card_env(store: StoreDep, cid: str, declared: Any) -> None:
    """422 unless bundle ``cid`` holds a card (model.json) whose ``env`` is ``declared``:
    ``loc`` names the bundle (``body.cid``) when the card is missing or unusable, else the
    first environment field that differs (``body.env.<field>``)."""
    try:
        card_cid, size = bundle_entry(store, cid, "model.json")
        if size > MAX_CARD_BYTES:
            raise ValueError(f"model.json is {size} bytes, the bound is {MAX_CARD_BYTES}")
        card = json.loads(store.get(card_cid, max_size=MAX_CARD_BYTES))
    except NotFound:
        field_error(
            ("body", "cid"),
            f"the content store does not hold {cid}: upload the bundle first",
            "bundle_not_found",
        )
    except KeyError:
        field_error(("body", "cid"), "the bundle has no model.json (its card)", "card_missing")
    except CIDMismatch as exc:
        raise RuleError(502, "content_corrupt", f"{cid} failed verification: {exc}") from None
    except StoreUnavailable as exc:
        raise RuleError(
            503, "store_unavailable", f"content store: {exc}", headers={"Retry-After": "5"}
        ) from None
    except (ValueError, RecursionError, StoreError) as exc:
        field_error(("body", "cid"), f"the bundle's card is unusable: {exc}", "card_invalid")
    env = card.get("env") if isinstance(card, dict) else None
    if not isinstance(env, dict):
        field_error(("body", "cid"), "the model's card has no 'env' object", "card_invalid")
    try:
        carded = validate_env(env)
    except SpecError as exc:
        field_error(("body", "cid"), f"the card's env is invalid: {exc}", "card_invalid")
    mine, theirs = declared.to_dict(), carded.to_dict()
    for name in mine:
        if mine[name] != theirs.get(name):
            field_error(
                ("body", "env", name),
                f"declared {mine[name]!r}, but the model's card says {theirs.get(name)!r}",
                "env_mismatch_card",
            )


def model_public(row: m.ModelRow, owner: m.WorkerRow | None) -> ModelPublic:
    return ModelPublic(
        id=row.id,
        cid=row.cid,
        owner=row.owner,
        domain=row.domain,
        env=row.env,
        agents=row.agents,
        walls_min=row.walls_min,
        walls_max=row.walls_max,
        reputation=from_fixed(row.reputation),
        allocations=row.alloc_count,
        rating=from_fixed(owner.sharing_rating if owner else HALF),
    )


MAX_SEARCH_WORDS = 8
"""Words of one ``q`` that are matched (the rest are ignored): each is one more LIKE scan."""


def _search_terms(q: str) -> list[Any]:
    """One condition per word of ``q`` (whitespace-separated, all must hold): the word in the
    description, the CID or the owner's address (any case), or, for a number, the model id.
    LIKE's wildcards in a word are literal."""
    terms = []
    for word in q.split()[:MAX_SEARCH_WORDS]:
        like = "%" + word.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_") + "%"
        options = [
            m.ModelRow.description.ilike(like, escape="\\"),
            m.ModelRow.cid.ilike(like, escape="\\"),
            m.ModelRow.owner.ilike(like, escape="\\"),
        ]
        number = word.removeprefix("#")
        if number.isascii() and number.isdigit() and len(number) < 19:
            options.append(m.ModelRow.id == int(number))
        terms.append(or_(*options))
    return terms


@router.get("", response_model=ModelsPublic)
def list_models(
    request: Request,
    session: SessionDep,
    domain: Annotated[int | None, Query(ge=0, le=MAX_DOMAIN)] = None,
    agents: Annotated[int | None, Query(ge=1, le=64)] = None,
    walls: Annotated[
        int | None, Query(ge=0, le=64, description="models trained with this many walls in range")
    ] = None,
    min_reputation: FractionQuery = None,
    owner: Address | None = None,
    q: Annotated[
        str | None,
        Query(
            min_length=1,
            max_length=100,
            pattern=r"^[^\x00-\x1f\x7f]+$",
            description=(
                "words that must all appear, each in the description, the CID or the owner's"
                " address, or be the model id (no control characters)"
            ),
        ),
    ] = None,
    sort: Literal["reputation", "newest", "allocations"] = "reputation",
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
    offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0,
) -> ModelsPublic:
    """Models matching every given filter; every word of q must match the description, the
    CID or the owner's address, or be the model id."""

    def build() -> dict[str, Any]:
        stmt = select(m.ModelRow)
        if domain is not None:
            stmt = stmt.where(m.ModelRow.domain == domain)
        if agents is not None:
            stmt = stmt.where(m.ModelRow.agents == agents)
        if walls is not None:
            stmt = stmt.where(m.ModelRow.walls_min <= walls, m.ModelRow.walls_max >= walls)
        if min_reputation is not None:
            stmt = stmt.where(m.ModelRow.reputation >= to_fixed(min_reputation))
        if owner is not None:
            stmt = stmt.where(m.ModelRow.owner == owner)  # checksummed by the Address type
        if q is not None:
            stmt = stmt.where(*_search_terms(q))
        count = session.scalar(select(func.count()).select_from(stmt.subquery())) or 0
        # Listing is the hot path (issue 7, "Overload"): plain columns with the owner's rating in
        # one query, serialised once (no ORM objects, no re-validation of the response model).
        page = (
            stmt.with_only_columns(*_LIST_COLUMNS, m.WorkerRow.sharing_rating)
            .outerjoin(m.WorkerRow, m.WorkerRow.address == m.ModelRow.owner)
            .order_by(*_SORT[sort])
            .limit(limit)
            .offset(offset)
        )
        data = [
            {
                **row._asdict(),
                "reputation": from_fixed(row.reputation),
                "allocations": row.alloc_count,
                "rating": from_fixed(HALF if row.sharing_rating is None else row.sharing_rating),
            }
            for row in session.execute(page)
        ]
        for item in data:
            del item["alloc_count"], item["sharing_rating"]
        return {"data": data, "count": count}

    return cached_page(request, session, build)  # type: ignore[return-value]


def allocations_public(
    session: SessionDep, allocs: list[m.AllocationRow]
) -> list[AllocationDetailPublic]:
    """``allocs`` with their models (id, CID, QoS, owner, review), read in one query whatever
    their number: a page of 500 allocations is 500 allocations, not 500 queries."""
    by_alloc: dict[int, list[AllocationModelPublic]] = {a.id: [] for a in allocs}
    if by_alloc:
        rows = session.execute(
            select(m.AllocatedModel, m.ModelRow.cid)
            .join(m.ModelRow, m.ModelRow.id == m.AllocatedModel.model_id, isouter=True)
            .where(m.AllocatedModel.alloc_id.in_(list(by_alloc)))
            .order_by(m.AllocatedModel.qos.desc(), m.AllocatedModel.model_id)
        ).all()
        for am, cid in rows:
            by_alloc[am.alloc_id].append(
                AllocationModelPublic(
                    id=am.model_id,
                    cid=cid or "",
                    qos=from_fixed(am.qos),
                    owner=am.owner,
                    review=am.review,
                )
            )
    return [
        AllocationDetailPublic(
            alloc_id=alloc.id,
            requester=alloc.requester,
            domain=alloc.domain,
            metric="model" if alloc.metric == int(Metric.MODEL) else "sharing",
            num_models=alloc.num_models,
            price_wei=alloc.price_wei,
            block_number=alloc.block_number,
            models=by_alloc[alloc.id],
        )
        for alloc in allocs
    ]


@router.get("/requests", response_model=AllocationsPublic)
def list_allocations(
    session: SessionDep,
    requester: Address | None = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
    offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0,
) -> AllocationsPublic:
    """Model allocations (MMC.allocateModel), newest first; ``requester`` filters. Three
    queries whatever ``limit``: the count, the page, the page's models."""
    stmt = select(m.AllocationRow)
    if requester is not None:
        stmt = stmt.where(m.AllocationRow.requester == requester)
    count = session.scalar(select(func.count()).select_from(stmt.subquery())) or 0
    page = session.scalars(stmt.order_by(m.AllocationRow.id.desc()).limit(limit).offset(offset))
    return AllocationsPublic(data=allocations_public(session, list(page)), count=count)


@router.get(
    "/requests/{alloc_id}", response_model=AllocationDetailPublic, responses=rule_responses(404)
)
def get_allocation(alloc_id: AllocId, session: SessionDep) -> AllocationDetailPublic:
    """One allocation: its models (id, CID, QoS, owner) and the requester's reviews."""
    alloc = session.get(m.AllocationRow, alloc_id)
    if alloc is None:
        raise RuleError(
            404, "allocation_not_found", f"no allocation {alloc_id} (or not indexed yet)"
        )
    [public] = allocations_public(session, [alloc])
    return public


def _model(session: SessionDep, model_id: int) -> m.ModelRow:
    row = session.get(m.ModelRow, model_id)
    if row is None:
        raise RuleError(404, "model_not_found", f"no model {model_id} (or not indexed yet)")
    return row


@router.get("/{model_id}", response_model=ModelDetailPublic, responses=rule_responses(404))
def get_model(model_id: ModelId, session: SessionDep, store: StoreDep) -> ModelDetailPublic:
    """A model as a model hub shows it: chain values in human units (reputations and QoS as
    fractions, prices in ETH), the producing task (the chain's outcome record), its experts,
    and the validated parts of its card (curve, held-out figures; an invalid part is left out)
    next to the raw card (model.json of the bundle, when the store has it)."""
    row = _model(session, model_id)
    owner = session.get(m.WorkerRow, row.owner)
    card = read_card(store, row.cid)
    view = CardView.from_card(card)
    # The outcome this model came from: submitted no later than the listing, by its owner
    # (MMC.addModel's provenance rule). An outcome submitted later with the same CID is
    # someone re-submitting a listed model as their own work: it says nothing about this one.
    produced = session.scalars(
        select(m.OutcomeRow)
        .where(
            m.OutcomeRow.cid == row.cid,
            m.OutcomeRow.worker == row.owner,
            m.OutcomeRow.block_number <= row.block_number,
        )
        .limit(1)
    ).first()
    task = session.get(m.TaskRow, produced.task_id) if produced is not None else None
    return ModelDetailPublic(
        **model_public(row, owner).model_dump(),
        description=row.description,
        card=card,
        metrics=card.get("metrics") if card else None,
        owner_reputation=from_fixed(owner.sharing_reputation if owner else HALF),
        owner_rating=from_fixed(owner.sharing_rating if owner else HALF),
        owner_model_reputation=_owner_model_reputation(session, row.owner),
        **view.model_dump(exclude={"expert_refs", "expert_usage"}),
        env_spec=_card_env(card),
        produced_by=ProducedByPublic(
            task_id=produced.task_id,
            worker=produced.worker,
            review=produced.review,
            accepted=produced.accepted,
        )
        if produced is not None
        else None,
        experts=_experts(session, _spec_experts(task), view.expert_refs, view.expert_usage),
        requests=_requests(session, model_id),
    )


def _card_env(card: dict[str, Any] | None) -> dict[str, Any] | None:
    try:
        return validate_env(card.get("env")).to_dict() if card else None
    except (SpecError, TypeError, ValueError):
        return None


def _spec_experts(task: m.TaskRow | None) -> list[str]:
    """The ``experts`` of a task's spec document (indexed from the store: checked here)."""
    experts = task.spec.get("experts") if task is not None and isinstance(task.spec, dict) else None
    if not isinstance(experts, list):
        return []
    refs = [e.get("model") if isinstance(e, dict) else e for e in experts]  # {model, qos} or ref
    return [r for r in refs if isinstance(r, str) and 0 < len(r) <= 200][:MAX_EXPERTS]


def _experts(
    session: SessionDep,
    from_spec: list[str],
    from_card: list[str],
    usage: dict[str, ExpertUsagePublic],
) -> list[ExpertPublic]:
    """Each expert once (the task spec's first: its CID is on chain), linked to its model,
    with what the card says the run did with it."""
    seen: dict[str, str] = {}
    for source, refs in (("task_spec", from_spec), ("card", from_card)):
        for ref in refs:
            seen.setdefault(ref, source)
    cids = [ref for ref in seen if is_cid(ref)]
    ids = (
        dict(
            session.execute(
                select(m.ModelRow.cid, func.min(m.ModelRow.id))
                .where(m.ModelRow.cid.in_(cids))
                .group_by(m.ModelRow.cid)
            ).all()
        )
        if cids
        else {}
    )
    return [
        ExpertPublic(
            ref=ref,
            cid=ref if is_cid(ref) else None,
            model_id=ids.get(ref),
            source=source,  # type: ignore[arg-type]
            usage=usage.get(ref),
        )
        for ref, source in seen.items()
    ]


def _requests(session: SessionDep, model_id: int) -> list[ModelRequestPublic]:
    rows = session.execute(
        select(m.AllocatedModel, m.AllocationRow)
        .join(m.AllocationRow, m.AllocationRow.id == m.AllocatedModel.alloc_id)
        .where(m.AllocatedModel.model_id == model_id)
        .order_by(m.AllocatedModel.alloc_id.desc())
        .limit(MAX_REQUESTS_SHOWN)
    ).all()
    return [
        ModelRequestPublic(
            alloc_id=a.alloc_id,
            requester=alloc.requester,
            qos=from_fixed(a.qos),
            price_wei=alloc.price_wei,
            price_eth=wei_to_eth(alloc.price_wei),
            review=a.review,
        )
        for a, alloc in rows
    ]


@router.get(
    "/{model_id}/download",
    responses={
        200: {"content": {"application/octet-stream": {}}},
        304: {"description": NOT_MODIFIED_DOC},
        **rule_responses(404, 413, 429, 502, 503),
    },
    response_class=StreamingResponse,
)
def download_model(
    model_id: ModelId,
    request: Request,
    session: SessionDep,
    store: StoreDep,
    settings: SettingsDep,
    file: BundleFile = "model.safetensors",
) -> Response:
    """The bytes of one bundle file, each block verified against the CID before it is sent,
    bounded by the manifest's size and the gateway's ``max_upload_bytes``."""
    row = _model(session, model_id)
    return _stream_bundle_file(request, store, settings, row.cid, file, f"model {model_id}")


@router.get(
    "/outcomes/{task_id}/{worker}/download",
    responses={
        200: {"content": {"application/octet-stream": {}}},
        304: {"description": NOT_MODIFIED_DOC},
        **rule_responses(401, 403, 404, 413, 429, 502, 503),
    },
    response_class=StreamingResponse,
)
def download_outcome(
    task_id: TaskId,
    worker: Address,
    request: Request,
    user: CurrentUser,
    session: SessionDep,
    store: StoreDep,
    settings: SettingsDep,
    file: BundleFile = "model.safetensors",
) -> Response:
    """A task's outcome (the bundle a worker submitted), streamed to the task's requester or
    that worker, whether or not it was shared; verified as ``/models/{id}/download``. This
    route is theirs; the content is not secret unless sealed: an outcome CID is on chain and
    its blocks are served to anyone (``/blocks``). Only a spec's ``outcome_key`` keeps the
    weights to the requester (docs/chain.md)."""
    task = session.get(m.TaskRow, task_id)
    if task is None:
        raise RuleError(404, "task_not_found", f"no task {task_id} (or not indexed yet)")
    if user.address not in (task.requester, worker):
        raise RuleError(
            403,
            "not_task_requester",
            f"this route streams task {task_id}'s outcomes to its requester "
            f"{task.requester} and each worker its own. An outcome is public content unless "
            "the task's spec sealed it to the requester (outcome_key): fetch a shared one as a "
            "model, or any by its CID block by block (/api/blocks)",
        )
    outcome = session.get(m.OutcomeRow, (task_id, worker))
    if outcome is None:
        raise RuleError(
            404, "outcome_not_found", f"{worker} submitted no outcome for task {task_id}"
        )
    return _stream_bundle_file(
        request, store, settings, outcome.cid, file, f"task {task_id}'s outcome by {worker}"
    )


class _DownloadStalled(Exception):
    """The client read nothing of a download for ``download_idle_timeout_s``."""


class _Download(StreamingResponse):
    """A bundle file streamed to its client, within bounds that hold however slowly the client
    reads: ``max_downloads_per_client`` at once per client address (429
    ``downloads_per_client``), ``max_downloads`` at once overall (503 ``downloads_busy``), and
    given up (connection closed) once the client has read nothing for
    ``download_idle_timeout_s``. It holds no in-flight slot once it starts
    (backend.api.shedding), so stalled downloads never answer other routes 503."""

    def __init__(self, content: Iterator[bytes], *, settings: Any, what: str, **kw: Any) -> None:
        super().__init__(content, **kw)
        self.idle_s = float(settings.download_idle_timeout_s)
        self.retry_after = int(settings.retry_after_s)
        self.what = what

    def _refusal(self, status_code: int, rule: str, msg: str) -> JSONResponse:
        return JSONResponse(
            status_code=status_code,
            content={"detail": {"rule": rule, "msg": msg}},
            headers={"Retry-After": str(self.retry_after)},
        )

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope.get(HEAD_ONLY):  # HEAD: the headers (size, CID), no bytes, no download slot
            await send({"type": "http.response.start", "status": self.status_code,
                        "headers": self.raw_headers})
            await send({"type": "http.response.body", "body": b"", "more_body": False})
            return
        pool: ClientSlots = scope["app"].state.download_pool
        client = client_key(scope)
        full = pool.take(client)
        if full == "client":
            await self._refusal(
                429,
                "downloads_per_client",
                f"at most {pool.per_client} downloads at once per client "
                "(max_downloads_per_client); finish one first",
            )(scope, receive, send)
            return
        if full == "total":
            await self._refusal(
                503,
                "downloads_busy",
                f"the gateway is at its limit of {pool.limit} downloads at once "
                f"(max_downloads); retry after {self.retry_after} s",
            )(scope, receive, send)
            return

        async def send_or_give_up(message: Any) -> None:
            try:  # a send waits while the client's buffers are full, i.e. it reads nothing
                await asyncio.wait_for(send(message), self.idle_s)
            except TimeoutError:
                raise _DownloadStalled from None

        try:
            await super().__call__(scope, receive, send_or_give_up)
        except _DownloadStalled:
            # returning unfinished makes the server close the connection (nothing more sent)
            log.warning(
                "download of %s to %s given up: nothing read for %g s",
                self.what,
                client,
                self.idle_s,
            )
        finally:
            pool.release(client)


def _stream_bundle_file(
    request: Request, store: StoreDep, settings: SettingsDep, cid: str, file: str, what: str
) -> Response:
    """Stream ``file`` of bundle ``cid``; 404/413/502 naming the rule before any byte, 429
    ``downloads_per_client`` / 503 ``downloads_busy`` past the download bounds
    (:class:`_Download`); 304 with no body (and no download slot) when ``If-None-Match``
    names the file's ETag, its CID, and the store holds it."""
    try:
        file_cid, size = bundle_entry(store, cid, file)
        sealed = file in sealed_envelopes(store, cid)
    except KeyError:
        raise RuleError(404, "bundle_file_missing", f"{what}'s bundle has no {file}") from None
    except NotFound:
        raise RuleError(404, "content_not_found", f"the store does not hold {cid}") from None
    except (ValueError, StoreError) as exc:
        raise RuleError(502, "bundle_invalid", f"{what}'s bundle is unusable: {exc}") from None
    if sealed and not store.has(file_cid):
        raise RuleError(
            404,
            "content_sealed",
            f"{what}'s {file} is sealed to the task's requester, who opens it locally with "
            "its key: `drlaas task pull TASK_ID --key KEY`",
        )
    if size > settings.max_upload_bytes:
        raise RuleError(
            413,
            "content_too_large",
            f"{file} is {size} bytes, the bound is {settings.max_upload_bytes}",
        )
    headers = {
        "Content-Length": str(size),
        "Content-Disposition": f'attachment; filename="{file}"',
        "ETag": f'"{file_cid}"',
        "X-Content-CID": file_cid,
    }
    if none_match(request, headers["ETag"]) and store.has(file_cid):
        return not_modified(headers)
    chunks = store.iter_get(file_cid, max_size=max(size, 1))
    try:
        first = next(chunks, b"")  # fail before the status line is sent when possible
    except NotFound:
        raise RuleError(404, "content_not_found", f"the store does not hold {file_cid}") from None
    except (CIDMismatch, ContentTooLarge, InvalidContent) as exc:
        # InvalidContent: blocks that hash right but are no UnixFS file (a directory node a
        # worker named as its weights): the bundle is bad, not the gateway
        raise RuleError(502, "content_corrupt", f"{file_cid} failed verification: {exc}") from None

    def body() -> Iterator[bytes]:
        sent = len(first)
        yield first
        for chunk in chunks:  # a later bad block raises: the connection is cut, never bad bytes
            sent += len(chunk)
            yield chunk
        if sent != size:
            raise CIDMismatch(file_cid, f"{sent} bytes", f"manifest says {size} bytes")

    media = "application/json" if file.endswith(".json") else "application/octet-stream"
    return _Download(
        body(),
        settings=settings,
        what=f"{what}'s {file}",
        media_type=media,
        headers=headers,
    )


@router.post(
    "/commitments",
    status_code=status.HTTP_201_CREATED,
    response_model=CommitmentPublic,
    responses=rule_responses(401, 403, 409, 503),
)
def commit_cid(body: CommitmentCreate, user: CurrentUser, chain: ChainDep) -> CommitmentPublic:
    """TMC.commitCid by the caller (a registered worker; 403 ``tasks_not_worker``): what an
    own upload needs before ``POST /models`` lists it, made before the upload so nobody who
    reads the store can list the CID first (``drlaas model push --key`` does it). Committing
    again keeps the first block."""
    committed_at = _commit(chain, user.address, bytes.fromhex(body.commitment[2:]))
    return CommitmentPublic(commitment=body.commitment.lower(), block=committed_at)


def _check_provenance(chain: ChainService, owner: str, cid: str, domain: int) -> bool:
    """The MMC's provenance rule (addModel reverts the same way), asked before the store is
    read: a task's outcome is listed only by its worker, once its requester accepted it, in
    its task's domain. Whether ``cid`` is a task's outcome (else an own upload:
    :func:`_ensure_committed`)."""
    worker, task_id, verdict = chain.call(chain.platform.tmc, "outcomeOf", cid_hash(cid))
    if not int(worker, 16):
        return False
    if worker.lower() != owner.lower():
        raise RuleError(403, "models_not_outcome_owner",
                        f"{cid} is the outcome of task {task_id} by {worker}: only its worker "
                        "lists it")
    if Verdict(verdict) != Verdict.ACCEPTED:
        raise RuleError(409, "models_outcome_not_accepted",
                        f"{cid} is an outcome of task {task_id} its requester has not accepted "
                        f"({Verdict(verdict).name.lower()}): it is listed once accepted")
    trained = int(chain.call(chain.platform.tmc, "taskDomain", task_id))
    if trained != domain:
        raise RuleError(409, "models_outcome_domain_mismatch",
                        f"{cid} is the outcome of task {task_id}, posted in domain {trained}: "
                        f"it is listed in that domain, not {domain}")
    return True


def _ensure_committed(chain: ChainService, owner: str, cid: str) -> None:
    """Commit-reveal (TMC.commitCid): an own upload (no task outcome; an outcome's record
    stands for the commitment) is listed only after ``owner`` committed keccak256(cid ++
    owner) in an earlier block. Commits for ``owner`` when it has not (409 ``sign_locally``
    with ``then: repeat`` for a key the gateway does not hold: relay the commitment, then send
    the same request again), and waits for a block after the commitment."""
    chain.await_block_after(_commit(chain, owner, cid_commitment(cid, owner), then="repeat"))


def _commit(chain: ChainService, owner: str, commitment: bytes, then: str = "") -> int:
    """The block of ``owner``'s ``commitment`` (TMC.commitCid), committing it first if it is
    not on chain (``then``: what a ``sign_locally`` client does after relaying it)."""
    committed_at = int(chain.call(chain.platform.tmc, "cidCommits", commitment))
    if not committed_at:
        rc = chain.send(
            owner,
            chain.platform.tmc,
            "commitCid",
            commitment,
            description="TMC.commitCid, the commitment to this CID that listing it needs",
            then=then,
        )
        committed_at = rc.block_number
    return committed_at


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    response_model=ModelPublic,
    responses=rule_responses(401, 402, 403, 409, 502, 503),
)
def share_model(
    body: ModelCreate,
    user: CurrentUser,
    chain: ChainDep,
    session: SessionDep,
    store: StoreDep,
    indexer: IndexerDep,
) -> ModelPublic:
    """MMC.addModel by the caller (a registered worker) for its bundle ``cid``: 422 when the
    declared environment differs from the bundle's card or the bundle is not a model the
    workers can use (``_check_bundle``: nothing is sent to the chain), 409
    ``model_already_listed``, and the MMC's provenance rule (403 ``models_not_outcome_owner``,
    409 ``models_outcome_not_accepted``, ``models_outcome_domain_mismatch``)."""
    declared = _env_spec(body.env, ("body", "env"))
    # the chain's cheap refusals before the store is read (the bundle check fetches up to
    # 64 MiB of weights): anyone can sign in and name any CID
    if not int(chain.call(chain.platform.umc, "workerId", user.address)):
        raise RuleError(403, "models_not_worker", f"{user.address} is not a registered worker: "
                        "register first (POST /users/workers)")
    listed = int(chain.call(chain.platform.mmc, "modelOfCid", cid_hash(body.cid)))
    if listed:
        raise RuleError(409, "model_already_listed", f"{body.cid} is listed as model {listed}")
    outcome = _check_provenance(chain, user.address, body.cid, body.domain)
    _check_card_env(store, body.cid, declared)
    _check_published(store, body.cid)
    _check_bundle(store, body.cid)
    attrs = env_attributes(declared)
    if not outcome:
        _ensure_committed(chain, user.address, body.cid)
    rc = chain.send(
        user.address, chain.platform.mmc, "addModel", body.cid, body.description, body.domain, attrs
    )
    model_id = int(rc.one("ModelAdded").args["modelId"])
    catch_up(indexer)
    session.expire_all()
    row = session.get(m.ModelRow, model_id)
    if row is None:  # indexer lagging (confirmations): answer from the event
        row = m.ModelRow(
            id=model_id,
            owner=user.address,
            domain=body.domain,
            cid=body.cid,
            env=attrs,
            agents=attrs[2],
            walls_min=attrs[4],
            walls_max=attrs[5],
            alloc_count=0,
            reputation=HALF,
            description=body.description,
        )
    return model_public(row, session.get(m.WorkerRow, user.address))


@router.post(
    "/requests",
    status_code=status.HTTP_201_CREATED,
    response_model=ModelAllocationPublic,
    responses=rule_responses(401, 402, 403, 409, 422, 503),
)
def request_models(
    body: ModelRequestCreate, user: CurrentUser, chain: ChainDep, indexer: IndexerDep
) -> ModelAllocationPublic:
    """MMC.allocateModel: the top ``num_models`` models by QoS (Eq. 13 or Eq. 22-23)."""
    attrs = _env_attrs(body.env, ("body", "env"))
    if body.weights and len(body.weights) != len(attrs):
        field_error(("body", "weights"), f"one weight per env attribute ({len(attrs)}), or none")
    if body.weights and sum(body.weights) != 1_000_000:
        field_error(("body", "weights"), "weights are fixed point (1e6 = 1) and must sum to 1e6")
    req = (
        body.domain,
        body.num_models,
        int(Metric.MODEL if body.metric == "model" else Metric.SHARING),
        to_fixed(body.min_reputation),
        to_fixed(body.min_rating),
        to_fixed(body.min_model_reputation),
        attrs,
        list(body.weights),
    )
    price = model_price(chain, body.price_wei)
    rc = chain.send(
        user.address,
        chain.platform.mmc,
        "allocateModel",
        req,
        value=price * body.num_models,
    )
    alloc_id = int(rc.one("ModelsRequested").args["allocId"])
    models = []
    for e in rc.named("ModelAllocated"):
        _, cid, _ = chain.call(chain.platform.mmc, "getModel", e.args["modelId"])
        models.append(
            AllocatedModelPublic(id=e.args["modelId"], cid=cid, qos=from_fixed(e.args["qos"]))
        )
    catch_up(indexer)
    return ModelAllocationPublic(alloc_id=alloc_id, models=models)


def model_price(chain: ChainDep, price_wei: int | None) -> int:
    """The price per model to pay: the given one, or the MMC's minimum when none is given; 422
    ``price_below_minimum`` on ``price_wei`` below that minimum (read from the chain: every
    allocation counts in the model's reputation, so none is free)."""
    minimum = int(chain.call(chain.platform.mmc, "minModelPrice"))
    if price_wei is None:
        return minimum
    if price_wei < minimum:
        field_error(
            ("body", "price_wei"),
            f"{price_wei} wei per model is below the minimum {minimum} wei (set by the consortium)",
            "price_below_minimum",
        )
    return price_wei


@router.post(
    "/requests/{alloc_id}/reviews",
    response_model=TxPublic,
    responses=rule_responses(401, 403, 404, 409),
)
def review_model(
    alloc_id: AllocId,
    body: ModelReviewCreate,
    user: CurrentUser,
    session: SessionDep,
    chain: ChainDep,
    indexer: IndexerDep,
) -> TxPublic:
    """MMC.updateModelRep by the allocation's requester (Eq. 10-11 reputations)."""
    alloc = session.get(m.AllocationRow, alloc_id)
    if alloc is not None and alloc.requester != user.address:
        raise RuleError(
            403, "not_allocation_requester", f"allocation {alloc_id} belongs to {alloc.requester}"
        )
    # Not indexed: the chain says whether it exists (the contract's own refusal of an unknown
    # allocation is NotAllocationRequester, a 403 that would hide the 404).
    if alloc is None and alloc_id > int(chain.call(chain.platform.mmc, "allocCount")):
        raise RuleError(404, "allocation_not_found", f"no allocation {alloc_id}")
    # MMC.AllocState: None, Allocated, Reviewed. The contract answers ModelsNotAllocated to
    # both None and Reviewed; a second review is named here (the contract still decides).
    if int(chain.call(chain.platform.mmc, "allocState", alloc_id, body.model_id)) == 2:
        raise RuleError(
            409,
            "model_already_reviewed",
            f"model {body.model_id} of allocation {alloc_id} was already reviewed (once each)",
        )
    rc = chain.send(
        user.address, chain.platform.mmc, "updateModelRep", alloc_id, body.model_id, body.review
    )
    catch_up(indexer)
    return TxPublic(**receipt_public(rc))


__all__ = ["router"]


def _owner_model_reputation(session: Any, owner: str) -> float:
    """Eq. 10 of ``owner``: total review over allocation count of all its listed models, as
    the MMC keeps it (``OwnerRecord``, qos.owner_totals)."""
    allocs, reviews = session.execute(
        select(func.coalesce(func.sum(m.ModelRow.alloc_count), 0),
               func.coalesce(func.sum(m.ModelRow.total_review), 0))
        .where(m.ModelRow.owner == owner)
    ).one()
    return from_fixed(mmc_reputation_fixed(int(reviews), int(allocs)))
