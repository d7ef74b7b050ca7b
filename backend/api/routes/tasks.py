"""Training tasks: create (spec to the content store, addTask + allocateTask), list, detail with
timeline/offers/outcomes/progress, progress points from assigned workers, reviews, cancel."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Path, Query, Request, status
from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError

from backend.api.cards import expert_trials
from backend.api.client_key import client_key
from backend.api.deps import ChainDep, CurrentUser, IndexerDep, SessionDep, SettingsDep, StoreDep
from backend.api.errors import RuleError, rule_responses
from backend.api.experts import (
    allocation_experts,
    check_experts,
    check_walls_cae,
    expert_specs,
    task_experts,
)
from backend.api.pagecache import cached_page
from backend.api.pending_specs import PendingSpecs
from backend.api.schemas import Address
from backend.api.writes import catch_up, field_error, receipt_public
from backend.chain.platform import OfferState, TaskStatus, WorkerStatus
from backend.db import models as m
from backend.schemas.common import (
    ID_DIGITS,
    MAX_DOMAIN,
    MAX_ID,
    EventPublic,
    TxPublic,
    from_fixed,
    to_fixed,
    wei_to_eth,
)
from backend.schemas.tasks import (
    OfferPublic,
    OutcomePublic,
    OutcomeTrialPublic,
    ProgressCreate,
    ProgressPublic,
    TaskCreate,
    TaskCreatedPublic,
    TaskDetailPublic,
    TaskExpertPublic,
    TaskPublic,
    TaskReviewCreate,
    TasksPublic,
)
from backend.services.specs import (
    SpecError,
    SpecLimitExceeded,
    check_limits,
    field_loc,
    validate_env,
)
from backend.settings import Settings
from backend.store import ContentStore, compute_cid
from backend.store.bundle import canonical_json
from backend.store.sealed import address_of, parse_public_key
from workers.mdrl.trainingspec import TrainingSpec

log = logging.getLogger(__name__)

router = APIRouter(prefix="/tasks", tags=["tasks"])
TaskId = Annotated[int, Path(ge=1, le=MAX_ID), ID_DIGITS]
PROGRESS_STATES = ("accepted", "submitted")
"""Offer states in which a worker posts curve points: from acceptance until its outcome is
reviewed (a point may arrive just after the submission)."""
MAX_PROGRESS_POINTS = 5_000
"""Curve points one worker may post for one task: each is a row, and an assigned worker could
otherwise post a point for every one of 10^12 steps (a long run posts one per update: ~750 for
12M steps)."""


def build_spec(
    body: TaskCreate, settings: Settings, experts: list[Any] | None = None
) -> TrainingSpec:
    """The task's TrainingSpec, within the platform limits; 422 naming the bad field or the
    limit (``spec_exceeds_memory_limit``, ``spec_exceeds_worker_hours_limit``). The payment
    minimum is the TMC's rule on the booked duration (:func:`check_min_reward`). ``experts``
    (from an allocation) replaces the body's."""
    doc = body.spec_document()
    if experts is not None:
        doc["experts"] = experts
    try:
        spec = TrainingSpec.from_dict(doc)
        check_limits(
            spec,
            num_workers=body.num_workers,
            max_memory_bytes=int(settings.max_job_memory_gb * 2**30),
            max_worker_hours=settings.max_task_worker_hours,
        )
    except SpecError as exc:
        field_error(("body", *field_loc(exc.field)), exc.msg)
    except SpecLimitExceeded as exc:
        raise RuleError(422, exc.rule, exc.msg) from None
    return spec


def check_outcome_key(spec: TrainingSpec, requester: str) -> None:
    """422 ``outcome_key_not_requester`` when the key the outcome is to be sealed to is not
    the caller's: a worker seals to the task's requester only (and checks it again)."""
    if spec.outcome_key is None:
        return
    owner = address_of(parse_public_key(spec.outcome_key))
    if owner.lower() != requester.lower():
        field_error(
            ("body", "outcome_key"),
            f"the key belongs to {owner}, not to the requester {requester}: outcomes are "
            "sealed to the task's requester",
            "outcome_key_not_requester",
        )


def check_duration(chain: ChainDep, deadline_s: int) -> None:
    """Before anything is sent: 422 ``tasks_bad_duration`` (the TMC's rule, same name as its
    revert) naming ``deadline_s`` when it is outside the TMC's bounds: at least the acceptance
    window plus ``minWorkTime``, at most ``maxDuration`` (consortium settings, read from the
    chain; the schema's minimum, 60 s, is only the contract's floor of ``minWorkTime``)."""
    shortest, longest = chain.platform.tmc.duration_bounds()
    if not shortest <= deadline_s <= longest:
        raise RuleError(
            422,
            "tasks_bad_duration",
            f"deadline_s {deadline_s} s is outside [{shortest}, {longest}] s: an offered "
            "worker needs its acceptance window plus the minimum work time, and a task lasts "
            "at most the consortium's maximum duration",
        )


def check_min_reward(chain: ChainDep, payment_wei: int, deadline_s: int) -> None:
    """Anti-spam, before anything is sent: 422 ``reward_below_minimum`` on ``payment_wei``
    when it is below the TMC's minimum for the task's duration (minRewardPerHour per
    worker-hour, rounded up; read from the chain, so the answer is the contract's)."""
    minimum = int(chain.call(chain.platform.tmc, "minRewardForDuration", deadline_s))
    if payment_wei < minimum:
        per_hour = int(chain.call(chain.platform.tmc, "minRewardPerHour"))
        field_error(
            ("body", "payment_wei"),
            f"{payment_wei} wei per worker is below the minimum {minimum} wei for "
            f"{deadline_s} s ({per_hour} wei per worker-hour, set by the consortium)",
            "reward_below_minimum",
        )


def check_requester_can_escrow(chain: ChainDep, address: str, escrow_wei: int) -> None:
    """Before the spec is stored: 403 ``tasks_not_requester`` unless ``address`` is a
    registered requester (the TMC's own rule, read from the chain; ``requester_pending`` while
    it waits for a consortium admin's approval), 402
    ``insufficient_funds`` unless it holds the escrow. Anyone can sign in, so nothing a
    stranger sends may leave blocks in the content store."""
    if not chain.call(chain.platform.umc, "isRequester", address):
        if int(chain.call(chain.platform.umc, "requesterStatus", address)) == WorkerStatus.PENDING:
            raise RuleError(
                403,
                "requester_pending",
                f"{address} is a requester waiting for a consortium admin's approval "
                "(POST /users/requesters/{address}/approval, by an admin)",
            )
        raise RuleError(
            403,
            "tasks_not_requester",
            f"{address} is not a registered requester: register first (POST /users/requesters)",
        )
    with chain.lock:
        balance = int(chain.chain.w3.eth.get_balance(address))  # type: ignore[arg-type]
    if balance < escrow_wei:
        raise RuleError(
            402,
            "insufficient_funds",
            f"{address} holds {balance} wei, the escrow is {escrow_wei} wei "
            "(payment_wei x num_workers) before gas",
        )


@router.post(
    "",
    status_code=status.HTTP_201_CREATED,
    response_model=TaskCreatedPublic,
    responses=rule_responses(400, 401, 402, 403, 409, 422, 503),
)
def create_task(
    request: Request,
    body: TaskCreate,
    user: CurrentUser,
    chain: ChainDep,
    store: StoreDep,
    indexer: IndexerDep,
    settings: SettingsDep,
    session: SessionDep,
) -> TaskCreatedPublic:
    """Store the spec, addTask with ``payment_wei * num_workers`` escrowed, then allocateTask.

    When the gateway cannot sign for the caller, the 409 ``sign_locally`` carries the addTask
    transaction; after relaying it via ``POST /tx`` the caller calls ``POST /tasks/{id}/allocate``.
    Experts (MEDC) are named by CID in ``experts`` or come from the caller's model allocation
    ``expert_allocation`` (``backend.api.experts``).
    """
    experts = None
    if body.expert_allocation is not None:
        if "experts" in body.model_fields_set and body.experts:
            field_error(
                ("body", "expert_allocation"), "give experts or expert_allocation, not both"
            )
        experts = allocation_experts(session, body.expert_allocation, user.address)
    spec = build_spec(body, settings, experts)
    check_outcome_key(spec, user.address)
    # who may post, before the store is read for up to 8 experts and a CAE
    check_requester_can_escrow(chain, user.address, body.payment_wei * body.num_workers)
    cards = check_experts(store, spec.experts)
    cae_card = check_walls_cae(
        store,
        spec.observation.walls_embedding,
        (spec.env.rows, spec.env.cols),
        spec.observation.walls_embedding_size,
    )
    if cards or cae_card is not None:  # the limits again, with the nets a worker loads too
        try:
            check_limits(
                spec,
                num_workers=body.num_workers,
                max_memory_bytes=int(settings.max_job_memory_gb * 2**30),
                max_worker_hours=settings.max_task_worker_hours,
                experts=expert_specs(spec, cards),
                walls_cae=cae_card,
            )
        except SpecLimitExceeded as exc:
            raise RuleError(422, exc.rule, exc.msg) from None
    check_duration(chain, body.deadline_s)
    check_min_reward(chain, body.payment_wei, body.deadline_s)
    # a caller who signs addTask itself may never relay it: a bounded number of its specs may
    # wait in the store for their task (backend.api.pending_specs)
    pending: PendingSpecs | None = getattr(request.app.state, "pending_specs", None)
    if chain.signer(user.address) is None and pending is not None:

        def on_chain(cids: Iterable[str]) -> set[str]:
            return set(
                session.scalars(
                    select(m.TaskRow.description).where(
                        m.TaskRow.requester == user.address, m.TaskRow.description.in_(list(cids))
                    )
                )
            )

        document = canonical_json(spec.to_dict())
        # counted in the step that admits it, before it is stored: parallel posts of one
        # address cannot all pass the bound before any of them counts
        pending.reserve(user.address, compute_cid(document), on_chain)
        spec_cid = store.add(document)
    else:
        spec_cid = store.add(canonical_json(spec.to_dict()))
    tmc = chain.platform.tmc
    params = (
        body.domain,
        body.num_workers,
        to_fixed(body.min_reputation),
        to_fixed(body.min_rating),
        body.min_cpu_cores,
        body.min_ram_gb,
        body.deadline_s,
        spec_cid,
    )
    rc = chain.send(
        user.address,
        tmc,
        "addTask",
        params,
        value=body.payment_wei * body.num_workers,
        description="TasksManager.addTask",
    )
    task_id = int(rc.one("TaskAdded").args["taskId"])
    try:
        rc2 = chain.send(user.address, tmc, "allocateTask", task_id)
    except Exception as exc:  # noqa: BLE001 - the task exists: answer it, whatever failed
        # addTask was mined and holds the escrow: an error without the task id made clients
        # post (and pay for) the task again while this one waited, allocated by nobody
        log.warning("task %d posted but not allocated: %r", task_id, exc)
        catch_up(indexer)
        return TaskCreatedPublic(
            task_id=task_id,
            spec_cid=spec_cid,
            offered=[],
            tx_hashes=[rc.tx_hash],
            allocation_error=_reason(exc),
        )
    catch_up(indexer)
    return TaskCreatedPublic(
        task_id=task_id,
        spec_cid=spec_cid,
        offered=[e.args["worker"] for e in rc2.named("TaskOffered")],
        tx_hashes=[rc.tx_hash, rc2.tx_hash],
    )


def _reason(exc: Exception) -> str:
    """A failure's rule and message for a client (never a Python traceback)."""
    rule, msg = getattr(exc, "rule", None), getattr(exc, "msg", None)
    if isinstance(rule, str) and isinstance(msg, str):
        return f"{rule}: {msg}"[:500]
    return f"{type(exc).__name__}: the allocation transaction failed"


def _task(session: SessionDep, task_id: int) -> m.TaskRow:
    t = session.get(m.TaskRow, task_id)
    if t is None:
        raise RuleError(404, "task_not_found", f"no task {task_id} (or not indexed yet)")
    return t


def _require_requester(t: m.TaskRow, address: str) -> None:
    if t.requester != address:
        raise RuleError(
            403, "not_task_requester", f"task {t.id} belongs to {t.requester}, not {address}"
        )


@router.post(
    "/{task_id}/allocate", response_model=TxPublic, responses=rule_responses(401, 403, 404, 409)
)
def allocate_task(
    task_id: TaskId, user: CurrentUser, session: SessionDep, chain: ChainDep, indexer: IndexerDep
) -> TxPublic:
    """allocateTask again: expired/declined offers go to the next best workers (thesis 7.6)."""
    _require_requester(_task(session, task_id), user.address)
    rc = chain.send(user.address, chain.platform.tmc, "allocateTask", task_id)
    catch_up(indexer)
    return TxPublic(**receipt_public(rc))


def task_env(env: Any) -> dict[str, Any] | None:
    """TaskEnvPublic of a spec's ``env`` (indexed from the store: parsed with the core's rules
    here); None when it does not parse."""
    try:
        spec = validate_env(env)
    except (SpecError, TypeError, ValueError):
        return None
    return {
        "rows": spec.rows,
        "cols": spec.cols,
        "agents": spec.agents,
        "walls": list(spec.walls),
        "moves": spec.moves,
        "intensity": {"kind": spec.intensity.kind, "values": list(spec.intensity.values)},
    }


def task_public(t: m.TaskRow) -> TaskPublic:
    return TaskPublic(
        id=t.id,
        requester=t.requester,
        domain=t.domain,
        status=t.status,
        num_workers=t.num_workers,
        reward_wei=t.reward_wei,
        reward_eth=wei_to_eth(t.reward_wei),
        env=task_env(t.spec.get("env")) if isinstance(t.spec, dict) else None,  # type: ignore[arg-type]
        deadline=t.deadline,
        min_reputation=from_fixed(t.min_reputation),
        min_rating=from_fixed(t.min_rating),
        min_cpu_cores=t.min_cpu_cores,
        min_ram_gb=t.min_ram_gb,
        description=t.description,
        offered=t.offered,
    )


@router.get("", response_model=TasksPublic)
def list_tasks(
    request: Request,
    session: SessionDep,
    status: Literal["open", "completed", "cancelled", "closed"] | None = None,
    requester: Address | None = None,
    worker: Address | None = None,
    domain: Annotated[int | None, Query(ge=0, le=MAX_DOMAIN)] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
    offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0,
) -> TasksPublic:
    """Tasks matching every given filter, newest first; ``worker`` = offered to that worker."""

    def build() -> dict[str, Any]:
        q = select(m.TaskRow)
        if status is not None:
            q = q.where(m.TaskRow.status == status)
        if requester is not None:
            q = q.where(m.TaskRow.requester == requester)
        if worker is not None:
            offered = select(m.OfferRow.task_id).where(m.OfferRow.worker == worker)
            q = q.where(m.TaskRow.id.in_(offered))
        if domain is not None:
            q = q.where(m.TaskRow.domain == domain)
        count = session.scalar(select(func.count()).select_from(q.subquery())) or 0
        # The hot path (docs/platform.md, "Overload"): plain columns, serialised once.
        # The spec's env only (JSON path on SQLite and PostgreSQL), not the whole document.
        page = (
            q.with_only_columns(*_LIST_COLUMNS, m.TaskRow.spec["env"].label("spec_env"))
            .order_by(m.TaskRow.id.desc())
            .limit(limit)
        )
        data = []
        for row in session.execute(page.offset(offset)):
            item = row._asdict()
            item.update(
                min_reputation=from_fixed(row.min_reputation),
                min_rating=from_fixed(row.min_rating),
                reward_eth=wei_to_eth(row.reward_wei),
                env=task_env(item.pop("spec_env")),
            )
            data.append(item)
        return {"data": data, "count": count}

    return cached_page(request, session, build)  # type: ignore[return-value]


_COMPUTED = ("reward_eth", "env")
_LIST_COLUMNS = tuple(
    getattr(m.TaskRow, name) for name in TaskPublic.model_fields if name not in _COMPUTED
)


def _with_trials(
    experts: list[dict[str, Any]], request: Request, outcomes: Sequence[m.OutcomeRow]
) -> list[TaskExpertPublic]:
    """The spec's experts, each with the workers' trials of it in their outcome cards (read
    from the store once per CID: ``backend.api.cards``). A store read takes one of the
    store-read slots (``deps.get_store``) when one is free; when none is, the page answers
    with the cards kept already, never refused: the task page does not depend on the store."""
    store: ContentStore | None = getattr(request.app.state, "store", None)
    trials: dict[str, list[Any]] = {}
    if experts and outcomes and store is not None:
        pairs = [(o.worker, o.cid) for o in outcomes]
        reads, client = request.app.state.store_reads, client_key(request)
        slot = reads.take(client) is None
        try:
            trials = expert_trials(request.app.state.outcome_cards, store, pairs, read=slot)
        finally:
            if slot:
                reads.release(client)
    return [
        TaskExpertPublic(
            **e,
            trials=[
                OutcomeTrialPublic(worker=w, **t.model_dump()) for w, t in trials.get(e["cid"], [])
            ],
        )
        for e in experts
    ]


@router.get("/{task_id}", response_model=TaskDetailPublic, responses=rule_responses(404))
def get_task(task_id: TaskId, session: SessionDep, request: Request) -> TaskDetailPublic:
    t = _task(session, task_id)
    events = session.scalars(
        select(m.ChainEvent)
        .where(m.ChainEvent.task_id == task_id, m.ChainEvent.contract == "TasksManager")
        .order_by(m.ChainEvent.block_number, m.ChainEvent.log_index)
    ).all()
    offers = session.scalars(
        select(m.OfferRow).where(m.OfferRow.task_id == task_id).order_by(m.OfferRow.block_number)
    ).all()
    outcomes = session.scalars(select(m.OutcomeRow).where(m.OutcomeRow.task_id == task_id)).all()
    listed = dict(  # a CID is listed once on the MMC (ModelsManager: provenance)
        session.execute(
            select(m.ModelRow.cid, m.ModelRow.id).where(
                m.ModelRow.cid.in_([o.cid for o in outcomes])
            )
        ).all()
    )
    progress = session.scalars(
        select(m.ProgressPoint)
        .where(m.ProgressPoint.task_id == task_id)
        .order_by(m.ProgressPoint.worker, m.ProgressPoint.step)
        .limit(10_000)
    ).all()
    return TaskDetailPublic(
        **task_public(t).model_dump(),
        spec=t.spec,
        spec_state=t.spec_state,
        experts=_with_trials(task_experts(session, t.spec, t.requester), request, outcomes),
        timeline=[EventPublic.model_validate(e) for e in events],
        offers=[
            OfferPublic(worker=o.worker, state=o.state, qos=from_fixed(o.qos), expiry=o.expiry)
            for o in offers
        ],
        outcomes=[
            OutcomePublic(
                worker=o.worker,
                cid=o.cid,
                review=o.review,
                accepted=o.accepted,
                model_id=listed.get(o.cid),
            )
            for o in outcomes
        ],
        progress=[
            ProgressPublic(
                worker=p.worker,
                step=p.step,
                success=p.success,
                time=p.time,
                cost=p.cost,
                extra=p.extra,
            )
            for p in progress
        ],
    )


@router.post(
    "/{task_id}/progress",
    status_code=status.HTTP_201_CREATED,
    response_model=ProgressPublic,
    responses=rule_responses(400, 401, 403, 404, 409),
)
def post_progress(
    task_id: TaskId, body: ProgressCreate, user: CurrentUser, session: SessionDep
) -> ProgressPublic:
    """A live curve point from a worker assigned to the task (accepted its offer)."""
    _task(session, task_id)
    # Lock the worker's offer row first (a row lock on PostgreSQL, the database's write lock on
    # SQLite) and hold it to the commit: two posts that both counted 4,999 points before either
    # inserted would otherwise both land, past MAX_PROGRESS_POINTS.
    session.execute(
        update(m.OfferRow)
        .where(m.OfferRow.task_id == task_id, m.OfferRow.worker == user.address)
        .values(state=m.OfferRow.state)
        .execution_options(synchronize_session=False)
    )
    offer = session.get(m.OfferRow, (task_id, user.address), populate_existing=True)
    if offer is not None and offer.state == "reviewed":
        raise RuleError(
            409,
            "progress_closed",
            f"the outcome of {user.address} for task {task_id} was reviewed: its curve is closed",
        )
    if offer is None or offer.state not in PROGRESS_STATES:
        raise RuleError(
            403,
            "not_assigned_worker",
            f"{user.address} is not an assigned worker of task {task_id}",
        )
    posted = session.scalar(
        select(func.count())
        .select_from(m.ProgressPoint)
        .where(m.ProgressPoint.task_id == task_id, m.ProgressPoint.worker == user.address)
    )
    if (posted or 0) >= MAX_PROGRESS_POINTS:
        raise RuleError(
            409,
            "progress_full",
            f"{user.address} has posted {MAX_PROGRESS_POINTS} points for task {task_id}, the most "
            "one worker may",
        )
    point = m.ProgressPoint(
        task_id=task_id,
        worker=user.address,
        step=body.step,
        success=body.success,
        time=body.time,
        cost=body.cost,
        extra=dict(body.model_extra or {}) or None,
    )
    session.add(point)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        raise RuleError(
            409, "progress_step_exists", f"step {body.step} of task {task_id} was already posted"
        ) from None
    return ProgressPublic(
        worker=point.worker,
        step=point.step,
        success=point.success,
        time=point.time,
        cost=point.cost,
        extra=point.extra,
    )


@router.post(
    "/{task_id}/reviews",
    response_model=TxPublic,
    responses=rule_responses(400, 401, 403, 404, 409),
)
def review_outcome(
    task_id: TaskId,
    body: TaskReviewCreate,
    user: CurrentUser,
    session: SessionDep,
    chain: ChainDep,
    indexer: IndexerDep,
) -> TxPublic:
    """TMC.reviewOutcome by the task's requester: review 0-5 and accept (pay) or reject;
    409 ``outcome_already_reviewed`` for an outcome reviewed before."""
    _require_requester(_task(session, task_id), user.address)
    _check_not_reviewed(session, chain, task_id, body.worker)
    rc = chain.send(
        user.address,
        chain.platform.tmc,
        "reviewOutcome",
        task_id,
        body.worker,
        body.review,
        body.accepted,
    )
    catch_up(indexer)
    return TxPublic(**receipt_public(rc))


def _check_not_reviewed(
    session: SessionDep, chain: ChainDep, task_id: int, worker: str
) -> None:
    """409 ``outcome_already_reviewed`` (with the verdict given) when the chain records the
    worker's offer as reviewed: the contract refuses a second review as
    ``TasksNotSubmitted``, which reads as if no outcome had been submitted. The chain's offer
    state decides (the index may lag); the review given is the index's, when it has it."""
    state, _, _, paid = chain.call(chain.platform.tmc, "getOffer", task_id, worker)
    if int(state) != OfferState.REVIEWED:
        return
    verdict = "accepted" if paid else "rejected"
    row = session.get(m.OutcomeRow, (task_id, worker))
    if row is not None and row.review is not None:
        done = f"reviewed ({row.review}/5, {verdict})"
    else:  # closing the task pays a submitted outcome unreviewed (OutcomePaidUnreviewed)
        done = f"reviewed or paid at the task's close ({verdict})"
    raise RuleError(
        409,
        "outcome_already_reviewed",
        f"the outcome of {worker} for task {task_id} was already {done}: an outcome is "
        "reviewed once",
    )


@router.post(
    "/{task_id}/cancel", response_model=TxPublic, responses=rule_responses(401, 403, 404, 409)
)
def cancel_task(
    task_id: TaskId, user: CurrentUser, session: SessionDep, chain: ChainDep, indexer: IndexerDep
) -> TxPublic:
    """Cancel an open task nobody accepted yet (escrow refunded to the requester's credit)."""
    _require_requester(_task(session, task_id), user.address)
    rc = chain.send(
        user.address, chain.platform.tmc, "updateTaskStatus", task_id, int(TaskStatus.CANCELLED)
    )
    catch_up(indexer)
    return TxPublic(**receipt_public(rc))


@router.post(
    "/{task_id}/cancel-open-slots",
    response_model=TxPublic,
    responses=rule_responses(401, 403, 404, 409),
)
def cancel_open_slots(
    task_id: TaskId, user: CurrentUser, session: SessionDep, chain: ChainDep, indexer: IndexerDep
) -> TxPublic:
    """Give up the slots no worker holds (TMC.cancelOpenSlots): their rewards are refunded to
    the requester's credit, workers who accepted keep theirs; 409 ``tasks_no_open_slot`` when
    every slot is accepted or inside a live offer."""
    _require_requester(_task(session, task_id), user.address)
    rc = chain.send(user.address, chain.platform.tmc, "cancelOpenSlots", task_id)
    catch_up(indexer)
    return TxPublic(**receipt_public(rc))
