"""The offer pipeline of a worker, free of Celery so it can be called and tested directly.

``OfferHandler.handle(task_id, worker)`` is idempotent: it reads the offer's state on chain and
the job's state in ``<worker data>/jobs/<chain identity>/<task_id>/state.json`` and continues
from where a previous attempt stopped (offered -> accepting -> accepted -> trained -> uploaded
-> submitted). The state records the task it was made for (requester, deadline, spec CID):
a directory of another task under the same id (the chain lost blocks and gave the id again)
is moved aside, never resumed. A spec with an ``outcome_key`` gets its weights sealed to the
requester (``backend.store.sealed``): the chain gets the plaintext bundle's CID, the store only
the card and the ciphertext. Transient failures (content store or chain node unreachable) raise
:class:`Transient`; the Celery job retries those with backoff.

An offer whose spec cannot be trained here (bad spec, estimated memory beyond this worker's RAM
share) is declined. A job that fails after acceptance (an exception in training or upload, a
spec found bad late) is marked ``failed``: it no longer holds capacity, and the task is given
back on chain at once (TMC ``abandonOffer``: the offer becomes ``Failed`` and the slot opens
for the requester to re-allocate). So is a job whose expert models (MEDC, the spec's
``experts``) cannot be fetched or fail verification (``workers.daemon.experts``): the reason
names the CID and what is wrong.

A job whose training process dies again and again without its checkpoint moving (killed for
memory, say) is given back after :data:`MAX_STARTS_WITHOUT_PROGRESS` starts instead of being
redelivered until the deadline; a start whose process died with the whole platform (a new
``drlaas up``, a reboot: :func:`daemon_session` changed) is not counted, nor one the daemon was
asked to stop during (SIGTERM, SIGINT: ``systemctl restart``, ``docker restart``, Ctrl-C, where
the session looks the same: :meth:`OfferHandler.note_stop` leaves :data:`STOP_MARK`). At daemon
start
:meth:`OfferHandler.recover` reconciles the job directories with the chain (a failure the
chain has not heard of is reported, a job still accepted, or offered and being checked, is
queued again, a finished job's checkpoint and fetched models are removed).
"""

from __future__ import annotations

import errno
import json
import logging
import os
import shutil
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import requests
from eth_account.signers.local import LocalAccount
from web3.exceptions import TimeExhausted

from backend.chain.addresses import checksum
from backend.chain.errors import ContractError
from backend.chain.platform import OfferState, Platform, TaskStatus, Verdict
from backend.store import ContentStore, NotFound, StoreError
from backend.store.bundle import read_bundle, upload_model
from backend.store.sealed import address_of, parse_public_key, publish_model, seal_model
from backend.store.staged import StagedUpload
from workers.daemon import job as jobs
from workers.daemon.capabilities import ram_bytes
from workers.daemon.experts import (
    CACHE_DIR,
    CAE_DIR,
    DEFAULT_CACHE_BYTES,
    DEFAULT_OFFER_FETCH_BYTES,
    EXPERTS_DIR,
    MAX_WEIGHTS_BYTES,
    STORE_OUTAGES,
    ExpertFetchError,
    ModelCache,
    check_expert_card,
    check_walls_cae_card,
    expert_key,
    fetch_experts,
    fetch_walls_cae,
    offer_fetch_bytes,
)
from workers.daemon.gateway import Gateway
from workers.daemon.links import task_spec_cid
from workers.daemon.progress_sender import LiveCurve, ProgressSender
from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.resources import (
    estimate,
    final_evaluation_seconds,
    log_bytes,
    max_updates,
    update_seconds,
)
from workers.mdrl.trainingspec import (
    JOB_EVAL_EPISODES,
    MAX_SPEC_BYTES,
    SpecError,
    TrainingSpec,
)

log = logging.getLogger(__name__)

#: Where a job keeps its staged outcome bundle until it is published (``_staged_outcome``).
OUTBOX_DIR = "outbox"
#: Times one delivery commits its uploaded outcome's CID again when the reveal finds the
#: commitment gone (a deep reorg dropped its block); past that the revert fails the job.
MAX_RECOMMITS = 3
#: The TMC's revert of a reveal whose commitment is not on chain (or not yet a block old).
CID_NOT_COMMITTED = "TasksCidNotCommitted"
#: Characters of a task's spec CID (its on-chain description, any text) a reason shows.
SHOWN_CID_CHARS = 120
#: Seconds kept free before the task deadline for upload and submitOutcome.
DEADLINE_MARGIN_S = 30.0
#: Phases a job goes through, in order (``state.json``).
PHASES = ("accepted", "trained", "uploaded", "submitted")
#: Phases of a job in hand: ``accepting`` is saved before the acceptOffer transaction, so a
#: process killed in between leaves a job that capacity and ``recover`` see.
IN_HAND = ("accepting", *PHASES[:-1])
#: Saved first when an offer is handled, before the checks (fetching experts can take
#: minutes): a daemon killed meanwhile leaves a job ``recover`` queues again while the offer
#: is live (a broker such as Redis redelivers its message only after hours). Not in hand:
#: it holds no capacity.
OFFERED = "offered"
#: Phases in which the delivered model exists and only its upload or a transaction is missing:
#: such a job is not given back while its deadline can still be met (``delivery_time_left``).
DELIVERABLE = ("trained", "uploaded")
#: Phases after which a job holds nothing on chain (``declined``: never accepted).
FINISHED = ("submitted", "declined", "closed", "failed")
#: Training starts in a row that got no further than the last one (the process died before
#: its checkpoint moved: killed for memory, say) before the job is given back.
MAX_STARTS_WITHOUT_PROGRESS = 3
#: Left in the job directory by :meth:`OfferHandler.note_stop` (the daemon asked to stop while
#: the job's training start ran): ``{"start": start_id, ...}``. That start ended by a stop, not
#: a death, and does not count toward MAX_STARTS_WITHOUT_PROGRESS. A file of its own, written
#: from the signal handler: rewriting state.json there could race the job's own ``_save``.
STOP_MARK = "stopped.json"
#: What a finished job no longer needs (``_prune``): the delivered model, metrics.csv and
#: progress.jsonl stay (``drlaas worker share`` reads the model).
PRUNED = ("run/checkpoint", "experts", "cae", "outbox")


class SpecNotFound(SpecError):
    """The task's spec is not in the store: a reason to decline an offer, but only a Transient
    failure for a job already accepted, whose spec the worker read when it accepted. A node
    that gave up finding it in time (``FindTimeout``) is a Transient failure either way."""


class Transient(RuntimeError):
    """A failure worth retrying later (service down); the message says which service."""


def node_unreachable(exc: BaseException) -> bool:
    """Whether a chain call failed because the node (or a proxy before it) is down, busy or
    slow, not because of the call itself: worth retrying (a 5xx or 429 answer, a connection or
    read timeout, a transaction not mined within the receipt wait)."""
    if isinstance(exc, (requests.ConnectionError, requests.Timeout, httpx.TransportError,
                        TimeExhausted, TimeoutError)):  # TimeoutError: no block after a commit
        return True
    if isinstance(exc, (requests.HTTPError, httpx.HTTPStatusError)):
        response = exc.response
        return response is None or response.status_code >= 500 or response.status_code == 429
    return False


def disk_full(exc: BaseException) -> bool:
    """Whether ``exc`` (or an exception it was raised from) is a full disk or quota: staging
    the outcome, a checkpoint or a state save on a full disk failed the job and threw away
    its trained model, where space freed later lets a retry finish it."""
    seen: set[int] = set()
    current: BaseException | None = exc
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        if isinstance(current, OSError) and current.errno in (errno.ENOSPC, errno.EDQUOT):
            return True
        current = current.__cause__ or current.__context__
    return False


@contextmanager
def chain_call(what: str) -> Iterator[None]:
    """Turn a failure of the node into :class:`Transient` (retried), naming ``what``."""
    try:
        yield
    except Exception as exc:
        if node_unreachable(exc):
            raise Transient(f"chain node unreachable during {what}: {exc}") from exc
        raise


class JobKeepsDying(RuntimeError):
    """Training was started MAX_STARTS_WITHOUT_PROGRESS times and the process died each time
    before its checkpoint moved: starting it again would only die again."""


def task_record(task: dict[str, Any], spec_cid: str) -> dict[str, Any]:
    """What tells one task from another under the same id (``state.json`` key ``task``): a
    chain that lost blocks numbers the next task as it numbered the lost one."""
    return {"requester": str(task["requester"]), "deadline": int(task["deadline"]),
            "spec": spec_cid}


def daemon_session() -> str:
    """What a restart of this daemon alone keeps and a restart of the platform changes: the
    host's boot and the process that started the daemon (``drlaas up`` starts a daemon that
    died again, under the same parent; a new ``drlaas up`` or a reboot is a new session).
    Empty parts where /proc does not tell."""
    try:
        boot = Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        boot = ""
    parent = os.getppid()
    try:  # field 22 (starttime): a parent pid reused by another process is another session
        started = Path(f"/proc/{parent}/stat").read_text().rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        started = ""
    return f"{boot}:{parent}:{started}"


@dataclass
class OfferHandler:
    account: LocalAccount
    platform: Platform
    store: ContentStore
    data_dir: Path
    gateway: Gateway | None = None
    max_jobs: int = 1
    memory_bytes: int = field(default_factory=ram_bytes)
    """RAM this worker's jobs may use together (measured); each job gets memory_bytes/max_jobs."""
    disk_free: Callable[[Path], int] = field(default=lambda path: shutil.disk_usage(path).free)
    """Free bytes of the disk holding a path (``_disk_short`` asks it of the data directory)."""
    checkpoint_every: int = jobs.CHECKPOINT_EVERY
    checkpoint_interval_s: float = jobs.CHECKPOINT_INTERVAL_S
    """Least seconds between two checkpoints of a job (0: every ``checkpoint_every`` updates)."""
    max_expert_bytes: int = MAX_WEIGHTS_BYTES
    """Bound on the weights of one expert model fetched for an MEDC job."""
    max_offer_fetch_bytes: int = DEFAULT_OFFER_FETCH_BYTES
    """Bound on the model bytes (not cached) checking one offer may download: past it the
    offer is declined on its manifests alone."""
    cache_bytes: int = DEFAULT_CACHE_BYTES
    """Bound on the model cache shared by this worker's jobs (``<data>/cache/models``; 0: none)."""
    clock: Callable[[], float] = time.time
    on_first_step: Callable[[int, int], None] | None = None
    session: str = field(default_factory=daemon_session)
    """This daemon's :func:`daemon_session`, recorded with each training start."""
    _progress: ProgressSender | None = field(default=None, init=False)
    _running: tuple[int, str] | None = field(default=None, init=False)
    """(task id, start id) of the training start in progress in this process (``note_stop``)."""
    _stop_noted: str | None = field(default=None, init=False)

    @property
    def cache(self) -> ModelCache | None:
        """The verified model bundles shared by this worker's jobs (None when disabled)."""
        if self.cache_bytes <= 0:
            return None
        return ModelCache(self.data_dir / CACHE_DIR, self.cache_bytes)

    @property
    def address(self) -> str:
        return str(self.account.address)

    def job_dir(self, task_id: int) -> Path:
        """``<data>/jobs/<chain identity>/<task id>``: a task id alone names different tasks on
        different chains (a restarted dev chain counts again from 1), so a job is never resumed,
        nor its model submitted, for a task of another chain."""
        return self._jobs_root / str(task_id)

    @property
    def _jobs_root(self) -> Path:
        return self.data_dir / "jobs" / self.platform.identity

    # -- job state -------------------------------------------------------------------------
    def _state(self, task_id: int) -> dict[str, Any]:
        """The job's state.json; {} when there is none. An unreadable one (a disk fault: the
        writes are atomic) is set aside as ``state.json.unreadable-<time>`` and logged, an empty
        one takes its place (the directory stays a job that recovery sees), and the job goes on
        from what the chain says (its checkpoint, if any, resumes it)."""
        f = self.job_dir(task_id) / "state.json"
        if not f.is_file():
            return {}
        try:
            state = json.loads(f.read_text())
            if not isinstance(state, dict):
                raise ValueError("not a JSON object")
            return state
        except (OSError, ValueError, RecursionError) as exc:
            kept = f.with_name(f"state.json.unreadable-{int(self.clock())}")
            os.replace(f, kept)
            f.write_text("{}")  # still a job directory: recovery rebuilds it from the chain
            log.error("task %s: job state %s unreadable (%s), set aside as %s", task_id, f,
                      type(exc).__name__, kept.name)
            return {}

    def _save(self, task_id: int, **changes: Any) -> dict[str, Any]:
        d = self.job_dir(task_id)
        d.mkdir(parents=True, exist_ok=True)
        state = {**self._state(task_id), **changes, "pid": os.getpid()}
        tmp = d / "state.json.tmp"
        with tmp.open("w") as fh:  # on disk before it replaces the old state (power loss)
            fh.write(json.dumps(state, indent=1))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, d / "state.json")
        return state

    def _jobs(self) -> Iterator[tuple[int, dict[str, Any]]]:
        """(task id, state) of every job directory of this chain, in task order; directories
        whose name is not a task id as this handler writes it (``1``, not ``01``) are not
        jobs."""
        root = self._jobs_root
        if not root.is_dir():
            return
        names = [d.name for d in root.iterdir() if (d / "state.json").is_file()]
        for name in sorted((n for n in names if _task_dir_name(n)), key=int):
            yield int(name), self._state(int(name))

    def active_jobs(self, exclude: int) -> list[int]:
        """Tasks of this chain that this worker accepted and has not submitted yet (other than
        ``exclude``). A job whose offer the chain no longer holds as accepted (task cancelled,
        closed or past its deadline) does not count, and is marked closed: capacity is never
        held by work nobody can submit."""
        out = []
        for tid, st in self._jobs():
            if tid == exclude or st.get("phase") in (*FINISHED, OFFERED):
                continue
            if self._settle(tid, st) is None:
                out.append(tid)
        return out

    def _settle(self, task_id: int, st: dict[str, Any]) -> str | None:
        """A job in hand on disk that the chain no longer holds as accepted is finished:
        ``submitted`` if the chain has its outcome (killed after submitOutcome, before its
        record), else ``closed`` (task cancelled, closed or past its deadline); returns that
        phase, or None while the chain still holds the job. A job ``offered`` or ``accepting``
        whose offer is still live (offered, not expired: killed during the checks, or before
        the acceptOffer transaction was sent) is held too: handling it again answers it."""
        with chain_call(f"reading the offer of task {task_id}"):
            offer = self.platform.tmc.offer(task_id, self.address)
            task = self.platform.tmc.task(task_id)
            now = self.platform.chain.now()
        state = offer["state"]
        live = task["status"] == TaskStatus.OPEN and int(task["deadline"]) > now
        if live and state == OfferState.ACCEPTED:
            return None
        if (
            live
            and state == OfferState.OFFERED
            and st.get("phase") in (OFFERED, "accepting")
            and int(offer.get("expiry", 0)) >= now
        ):
            return None
        if state in (OfferState.SUBMITTED, OfferState.REVIEWED) and st.get("cid"):
            self._close(task_id, phase="submitted")
            return "submitted"
        self._close(task_id, phase="closed", reason="offer no longer accepted on chain")
        return "closed"

    # -- the pipeline ----------------------------------------------------------------------
    def handle(self, task_id: int, worker: str) -> dict[str, Any]:
        """Accept (or decline) the offer, train, upload, submit; returns what happened."""
        if checksum(worker) != self.address:
            raise ValueError(
                f"offer for {checksum(worker)} delivered to the daemon of {self.address}: "
                f"queues must be per worker"
            )
        tmc = self.platform.tmc
        with chain_call(f"reading the offer of task {task_id}"):
            offer = tmc.offer(task_id, self.address)
            task = tmc.task(task_id)
        state = OfferState(offer["state"])
        if state in (OfferState.SUBMITTED, OfferState.REVIEWED):
            st = self._state(task_id)
            if st.get("phase") != "submitted" and st.get("cid"):  # killed before its record
                st = self._close(task_id, phase="submitted")
            return {"task_id": task_id, "status": "submitted", "cid": st.get("cid")}
        if task["status"] != TaskStatus.OPEN:
            return {"task_id": task_id, "status": f"task {TaskStatus(task['status']).name.lower()}"}
        if state not in (OfferState.OFFERED, OfferState.ACCEPTED):
            self._close(task_id, phase="closed", offer=state.name.lower())
            return {"task_id": task_id, "status": f"offer {state.name.lower()}"}

        with chain_call(f"reading the spec CID of task {task_id}"):
            spec_cid = task_spec_cid(self.platform, task_id)
        self._claim(task_id, task_record(task, spec_cid),
                    offer if state == OfferState.OFFERED else None)
        if state == OfferState.ACCEPTED and self._state(task_id).get("phase") == "failed":
            return self._report_failure(task_id)
        spec = self._fetch_spec(task_id, spec_cid)
        if state == OfferState.OFFERED:
            reason = self._cannot_take(
                task_id, spec, str(task["requester"]), deadline=int(task["deadline"])
            )
            if reason is not None:
                self._transact("declineOffer", task_id)
                self._save(task_id, phase="declined", reason=reason)
                return {"task_id": task_id, "status": "declined", "reason": reason}
            with chain_call(f"reading the clock for task {task_id}"):
                late = int(offer["expiry"]) < self.platform.chain.now()
            if late:  # the checks (fetching the experts) outlasted the acceptance window
                self._close(task_id, phase="closed", reason="the offer expired during the checks")
                return {"task_id": task_id, "status": "offer expired"}
            self._save(task_id, phase="accepting")
            self._transact("acceptOffer", task_id)
            self._save(task_id, phase="accepted", accepted_at=self.clock())
        elif isinstance(spec, SpecNotFound):  # read when accepted: the node is slow, retry
            raise Transient(str(spec))
        elif isinstance(spec, SpecError):  # accepted earlier, spec cannot be trained: give up
            return self._fail(task_id, f"task spec: {spec}")

        try:
            return self._run(task_id, spec, task)  # type: ignore[arg-type]
        except Transient:
            raise
        except Exception as exc:  # noqa: BLE001 - any failure of the job releases the worker
            if disk_full(exc):  # the worker's disk, not the job: keep what is trained, retry
                raise Transient(
                    f"the worker's disk is full (free space under {self.data_dir}; the job "
                    f"and its trained model are kept): {exc}") from exc
            log.exception("task %s: job failed", task_id)
            return self._fail(task_id, f"{type(exc).__name__}: {exc}")

    def _claim(self, task_id: int, record: dict[str, Any], offer: dict[str, Any] | None) -> None:
        """Make the job directory this task's before anything in it is used: one recorded for
        another task under this id (the chain lost the blocks of the task it was made for, and
        numbered a new task the same) is moved aside, so the new task is never answered with
        the old one's model. Records the task and, for an offer not answered yet, the phase
        ``offered`` (OFFERED) with its expiry."""
        st = self._state(task_id)
        known = st.get("task")
        if isinstance(known, dict) and any(
            key in known and known[key] != value for key, value in record.items()
        ):
            self._set_aside(task_id, f"made for task {known}, the chain's is {record}")
            st = {}
        changes: dict[str, Any] = {}
        if known != record or not st:
            changes["task"] = record
        if offer is not None and st.get("phase") not in IN_HAND:
            if st.get("phase") != OFFERED or st.get("offer_expiry") != int(offer["expiry"]):
                changes |= {"phase": OFFERED, "offer_expiry": int(offer["expiry"])}
        if changes:
            self._save(task_id, **changes)

    def _set_aside(self, task_id: int, why: str) -> None:
        """Move the job directory to ``<task id>.replaced-<time>`` (not a task id: no longer a
        job that recovery or capacity see), kept for inspection."""
        d = self.job_dir(task_id)
        kept = d.with_name(f"{d.name}.replaced-{int(self.clock())}")
        n = 1
        while kept.exists():
            kept, n = d.with_name(f"{d.name}.replaced-{int(self.clock())}-{n}"), n + 1
        os.replace(d, kept)
        self._drop_progress(task_id)
        log.error("task %s: job directory %s %s: moved aside as %s", task_id, d, why, kept.name)

    def _run(self, task_id: int, spec: TrainingSpec, task: dict[str, Any]) -> dict[str, Any]:
        """Train (or resume), upload and submit an accepted job."""
        st = self._state(task_id)
        model_dir = jobs.delivered_model(self.job_dir(task_id), spec)
        if (
            st.get("phase") not in ("trained", "uploaded")
            or not (model_dir / "model.json").is_file()
        ):
            # killed after training, before this record: the finished model, not more updates
            finished = jobs.finished_training(self.job_dir(task_id), spec)
            model_dir = finished or self._train(task_id, spec, deadline=int(task["deadline"]))
            st = self._save(  # model | best; a bundle staged from an earlier model is stale
                task_id, phase="trained", model=model_dir.name, starts_without_progress=0,
                staged_cid=None,
            )
        if st.get("phase") != "uploaded" or not st.get("cid"):
            # commit-reveal: the CID is committed on chain before anyone can read it in the
            # store, so nobody can hand it in ahead of us (TMC.commitCid, docs/chain.md)
            staged, cid = self._staged_outcome(task_id, spec, model_dir, st)
            with chain_call(f"committing the outcome CID of task {task_id}"):
                self.platform.tmc.commit_cid(self.address, cid)
            try:
                staged.publish(self.store)
                files = {name: entry[0] for name, entry in read_bundle(self.store, cid).items()}
            except STORE_OUTAGES as exc:
                raise Transient(str(exc)) from exc
            st = self._save(task_id, phase="uploaded", cid=cid, files=files)
            shutil.rmtree(self.job_dir(task_id) / OUTBOX_DIR, ignore_errors=True)  # published
        cid = st["cid"]
        self._flush_progress(task_id, wait_s=5.0)  # the curve is complete before the outcome
        recommits = 0
        while True:
            try:
                rc = self._transact("submitOutcome", task_id, cid)
                break
            except ContractError as exc:
                with chain_call(f"reading the offer of task {task_id}"):
                    now = OfferState(self.platform.tmc.offer(task_id, self.address)["state"])
                if now in (OfferState.SUBMITTED, OfferState.REVIEWED):
                    # an earlier try whose receipt wait timed out was mined after all
                    self._close(task_id, phase="submitted", submitted_at=self.clock())
                    return {"task_id": task_id, "status": "submitted", "cid": cid}
                if exc.name != CID_NOT_COMMITTED or recommits >= MAX_RECOMMITS:
                    raise
                recommits += 1
                self._recommit(task_id, cid, recommits)
        self._close(task_id, phase="submitted", tx=rc.tx_hash, submitted_at=self.clock())
        return {"task_id": task_id, "status": "submitted", "cid": cid, "tx": rc.tx_hash}

    def _recommit(self, task_id: int, cid: str, attempt: int) -> None:
        """Commit the uploaded outcome's CID again: its commitment is gone from the chain
        (the blocks holding it were lost in a reorg, or the contract evicted it), and the
        reveal reverted. The job failed there before, though its model was uploaded and its
        deadline ahead. The CID is readable in the store by now, so a copier could commit it
        first; still the only way to deliver."""
        log.warning(
            "task %s: the commitment of outcome %s is no longer on chain (a reorg, or "
            "evicted) and submitOutcome reverted; committing it again (%d of %d)",
            task_id, cid, attempt, MAX_RECOMMITS)
        with chain_call(f"committing the outcome CID of task {task_id} again"):
            self.platform.tmc.commit_cid(self.address, cid)
        self._save(task_id, recommits=_count(self._state(task_id), "recommits") + 1)

    def _staged_outcome(
        self, task_id: int, spec: TrainingSpec, model_dir: Path, st: dict[str, Any]
    ) -> tuple[StagedUpload, str]:
        """The outcome bundle, staged (its CID known, nothing published) and saved in the job
        directory before its CID is committed: a retry after a store outage or a kill
        publishes those same bytes under the committed CID. Sealing again would encrypt with
        a fresh key, giving another CID, another commitment, and an orphaned first bundle."""
        outbox = self.job_dir(task_id) / OUTBOX_DIR
        if st.get("staged_cid"):
            try:
                return StagedUpload.load(outbox), str(st["staged_cid"])
            except ValueError as exc:  # killed while saving it: nothing was committed yet
                log.warning("task %s: staging the outcome again: %s", task_id, exc)
        staged = StagedUpload()
        cid = (
            seal_model(staged, model_dir, parse_public_key(spec.outcome_key))
            if spec.outcome_key is not None
            else upload_model(staged, model_dir)
        )
        staged.save(outbox)
        self._save(task_id, staged_cid=cid)
        return staged, cid

    # -- capacity and failure --------------------------------------------------------------
    def _cannot_take(
        self, task_id: int, spec: TrainingSpec | SpecError, requester: str, *, deadline: int
    ) -> str | None:
        """Why this worker must decline the offer (None: it can take it)."""
        if isinstance(spec, SpecError):
            return str(spec)
        if spec.outcome_key is not None:  # seal only to the requester the chain names
            owner = address_of(parse_public_key(spec.outcome_key))
            if owner.lower() != requester.lower():
                return f"outcome_key belongs to {owner}, not to the task's requester {requester}"
        # before any expert's manifest or card is fetched (up to max_offer_fetch_bytes): an
        # offer whose spec alone exceeds this worker's memory, or whose deadline passed or
        # cannot hold one update, is declined on its spec
        early = (self._memory_short(spec) or self._disk_short(spec, deadline)
                 or self._deadline_too_near(spec, deadline))
        if early is not None:
            return early
        cae_card, guides = None, []  # what the run loads besides its own nets (their cards)
        cache = self.cache
        try:  # a reference no worker can fetch, models over the bounds (on their manifests,
            # before any card or weights), and an expert whose card no worker can use
            keys = [expert_key(ref) for ref in spec.experts]
            if len(set(keys)) != len(keys):  # the spec's check compares text; CIDs have spellings
                return "experts: the same model twice (one CID in two spellings)"
            demo = spec.demonstration()
            cae = spec.observation.walls_embedding
            models = ([cae] if cae is not None else []) + list(demo.experts if demo else ())
            fetch = offer_fetch_bytes(
                self.store, models, max_weights=self.max_expert_bytes, cache=cache
            )
            if fetch > self.max_offer_fetch_bytes:
                return (
                    f"experts_too_large: checking this offer would download {fetch} bytes of "
                    f"expert models and walls CAE, this worker downloads at most "
                    f"{self.max_offer_fetch_bytes} per offer"
                )
            if cae is not None:
                cae_card = check_walls_cae_card(
                    self.store,
                    cae,
                    max_weights=self.max_expert_bytes,
                    grid=(spec.env.rows, spec.env.cols),
                    embedding=spec.observation.walls_embedding_size,
                    cache=cache,
                )
            for ref in demo.experts if demo is not None else ():
                guides.append(check_expert_card(
                    self.store, ref, max_weights=self.max_expert_bytes, task=spec.env,
                    cache=cache,
                ))
        except ExpertFetchError as exc:
            return str(exc)
        except STORE_OUTAGES as exc:
            raise Transient(f"cannot read the task's expert models: {exc}") from exc
        busy = self.active_jobs(exclude=task_id)
        if len(busy) >= self.max_jobs:
            return "at capacity"
        short = self._memory_short(spec, guides, cae_card)
        if short is not None:
            return short
        late = self._deadline_too_near(spec, deadline)  # again: the checks above took time
        if late is not None:
            return late
        try:  # walls the spec's bounds allow can still leave the team no room (env.LayoutError)
            TargetLocalizationEnv(spec.env, 1, seed=spec.seed)
        except ValueError as exc:  # LayoutError, or an env rule the spec check does not mirror
            return f"env: {exc}"
        return self._models_unusable(task_id, spec)

    def _memory_short(
        self, spec: TrainingSpec, guides: list[Any] | None = None, cae_card: Any = None
    ) -> str | None:
        """Why this worker's memory per job cannot hold ``spec`` with its experts' and walls
        CAE's nets (their cards; each expert already passed expert_misfit, so each can be laid
        on the task's grid), None if it can. Integer arithmetic, nothing allocated; without
        the cards (before they are fetched) a lower bound."""
        guides = guides or []
        share = self.memory_bytes // max(1, self.max_jobs)
        need = estimate(spec, experts=guides, walls_cae=cae_card).memory_bytes
        if need <= share:
            return None
        extra = f" with its {len(guides)} expert(s)" if guides else ""
        return (
            f"spec_exceeds_worker_memory: needs about {need / 2**30:.3g} GiB{extra}, this "
            f"worker has {share / 2**30:.3g} GiB per job"
        )

    def _disk_short(self, spec: TrainingSpec, deadline: int) -> str | None:
        """Why this worker's free disk cannot hold the logs of ``spec`` (None: it can): a job
        appends a metrics row and a progress line per update (``resources.log_bytes``), as
        many as its budget and deadline allow, and may use half the free disk of its share
        (the other half: checkpoints, models, the store)."""
        try:
            free = self.disk_free(self.data_dir if self.data_dir.exists() else Path("."))
        except OSError:
            return None  # not measurable here: the other checks stand
        share = free // (2 * max(1, self.max_jobs))
        left_s = max(0.0, deadline - self.clock())
        need = log_bytes(spec, left_s)
        if need <= share:
            return None
        return (
            f"spec_exceeds_worker_disk: up to {max_updates(spec, left_s):,} PPO updates of "
            f"{spec.ppo.batch_steps:,} env steps before its deadline log about "
            f"{need / 2**30:.3g} GiB (a metrics row and a progress line each), this worker "
            f"has {share / 2**30:.3g} GiB of disk per job"
        )

    def _deadline_too_near(self, spec: TrainingSpec, deadline: int) -> str | None:
        """Why the task's deadline (less DEADLINE_MARGIN_S) cannot hold this job (None: it
        can). The time budget is checked between updates only, and the final evaluation runs
        after the last update whatever the time left: a job runs at least one update and that
        (``resources.update_seconds`` + ``final_evaluation_seconds``). Pure arithmetic on the
        spec and the clock: ``_cannot_take`` asks it before fetching anything, and again after
        the expert checks, which can take minutes."""
        left_s = deadline - self.clock() - DEADLINE_MARGIN_S
        one_update_s = update_seconds(spec)
        final_s = final_evaluation_seconds(spec)
        if one_update_s + final_s > left_s:
            return (
                f"deadline: one PPO update and the final evaluation ({JOB_EVAL_EPISODES} "
                f"episodes of up to env.max_steps = {spec.env.max_steps} steps) of this spec "
                f"take about {one_update_s + final_s:.0f} s (resource model), the task's "
                f"deadline leaves {max(left_s, 0):.0f} s"
            )
        return None

    def _models_unusable(self, task_id: int, spec: TrainingSpec) -> str | None:
        """Why the experts or walls CAE of ``spec`` cannot run (None: they can), found by
        doing now what the job would do after acceptance: fetch each, verified against its CID
        (into the job directory, where the job finds them and fetches nothing again), and load
        it as the run will (``job.check_job_models``). A bundle whose weights the store lacks,
        differ from the manifest or contradict the card, or a card whose input shape or
        embedding size the task cannot give, is a decline, not a job failed on chain at this
        worker's reputation. Last of the checks: the memory check counted these nets first."""
        demo = spec.demonstration()
        cae = spec.observation.walls_embedding
        if demo is None and cae is None:
            return None
        job, cache = self.job_dir(task_id), self.cache
        try:
            experts = fetch_experts(self.store, demo.experts if demo is not None else (), job,
                                    max_weights=self.max_expert_bytes, cache=cache)
            walls = (fetch_walls_cae(self.store, cae, job, max_weights=self.max_expert_bytes,
                                     cache=cache)
                     if cae is not None else None)
            jobs.check_job_models(spec, experts, walls)
        except ExpertFetchError as exc:
            for sub in (EXPERTS_DIR, CAE_DIR):  # nothing of a declined task stays in the job
                shutil.rmtree(job / sub, ignore_errors=True)  # (the cache keeps the bytes)
            return str(exc)
        except STORE_OUTAGES as exc:
            raise Transient(f"cannot fetch the task's expert models: {exc}") from exc
        return None

    def delivery_time_left(self, task_id: int) -> float | None:
        """Seconds left before the deadline less DEADLINE_MARGIN_S for a job in hand whose
        model is trained (only its upload or a transaction is missing); None for any other job.
        While this is positive the Celery job keeps retrying a store or node outage instead of
        giving the job back: that would throw away a model that may still be delivered."""
        st = self._state(task_id)
        phase = st.get("phase")
        if phase not in IN_HAND:
            return None
        if phase not in DELIVERABLE and not (self.job_dir(task_id) / jobs.FINISHED_MARK).is_file():
            return None
        record = st.get("task")
        deadline = record.get("deadline") if isinstance(record, dict) else None
        if not isinstance(deadline, int):  # a job recorded before its task was (or damaged)
            try:
                with chain_call(f"reading the deadline of task {task_id}"):
                    deadline = int(self.platform.tmc.task(task_id)["deadline"])
            except Transient:
                return None  # unknown: give up as before
        return deadline - DEADLINE_MARGIN_S - self.clock()

    def give_up(self, task_id: int, reason: str) -> dict[str, Any]:
        """The job's retries ran out (the store or the node stayed down): a job accepted and
        not yet submitted fails and is given back on chain, instead of its offer staying
        accepted, and the worker busy, until the deadline with nobody working on it. An offer
        still being checked (the spec or an expert could not be fetched) is declined, so the
        requester can offer the slot to the next worker at once instead of at its expiry."""
        phase = self._state(task_id).get("phase")
        if phase in IN_HAND:
            return self._fail(task_id, reason)
        if phase == OFFERED:
            with chain_call(f"reading the offer of task {task_id}"):
                offer = self.platform.tmc.offer(task_id, self.address)
                task = self.platform.tmc.task(task_id)
            if (OfferState(offer["state"]) == OfferState.OFFERED
                    and task["status"] == TaskStatus.OPEN):
                self._transact("declineOffer", task_id)
                self._save(task_id, phase="declined", reason=reason[:2000])
                return {"task_id": task_id, "status": "declined", "reason": reason}
        return {"task_id": task_id, "status": "given up", "reason": reason}

    def _fail(self, task_id: int, reason: str) -> dict[str, Any]:
        """Mark an accepted job failed (it stops counting against capacity) and report it."""
        self._close(task_id, phase="failed", reason=reason[:2000], failed_at=self.clock())
        return self._report_failure(task_id)

    def _close(self, task_id: int, **changes: Any) -> dict[str, Any]:
        """Save a finished phase (FINISHED) and prune what the job no longer needs."""
        state = self._save(task_id, **changes)
        self._prune(task_id)
        self._drop_progress(task_id)  # points a finished job never sent
        return state

    def _prune(self, task_id: int) -> None:
        """Remove a finished job's checkpoint and fetched expert models and CAE (PRUNED): a
        worker's disk does not fill up with jobs it will never resume."""
        for part in PRUNED:
            shutil.rmtree(self.job_dir(task_id) / part, ignore_errors=True)
        (self.job_dir(task_id) / STOP_MARK).unlink(missing_ok=True)
        for left in jobs.run_dir(self.job_dir(task_id)).glob("checkpoint.*"):  # set aside, swaps
            shutil.rmtree(left, ignore_errors=True)

    def recover(
        self, enqueue: Callable[[int, str], None] | None = None, only: set[int] | None = None
    ) -> dict[str, list[int]]:
        """Reconcile this chain's job directories (or the tasks in ``only``) with the chain at
        daemon start; returns the task ids by what was done.

        * ``reported``: failed jobs whose ``abandonOffer`` never reached the chain (the node was
          down when the job gave up) are given back now;
        * ``queued``: jobs in hand (accepting, accepted, trained, uploaded) that the chain still
          holds as accepted (or, for ``offered`` and ``accepting``, still offers) go to
          ``enqueue(task_id, worker)`` again: their message may be gone
          (a broker restarted without persistence). A duplicate is harmless: the handler is
          idempotent and the daemon's solo pool runs one job at a time. So does a job whose
          state.json was unreadable (set aside by ``_state``) when the chain holds it;
        * ``submitted``: jobs in hand whose outcome the chain has (killed after submitOutcome,
          before its record) are recorded as submitted (``drlaas worker share`` needs that);
        * ``closed``: jobs in hand that the chain no longer holds (cancelled, closed, past the
          deadline) are closed;
        * ``pruned``: finished jobs lose their checkpoint and fetched models (``_prune``);
        * ``deferred``: jobs whose reconciliation failed (the node down: after the first
          :class:`Transient` the other jobs that need the chain are not tried; or an error of
          that one job, logged). The rest of the scan goes on; the caller retries these with
          ``only`` (``recover_jobs`` does, in the background)."""
        done: dict[str, list[int]] = {
            "reported": [], "queued": [], "submitted": [], "closed": [], "pruned": [],
            "deferred": [],
        }
        node_down = False
        for tid, st in self._jobs():
            if only is not None and tid not in only:
                continue
            phase = st.get("phase")
            needs_chain = phase not in FINISHED or (phase == "failed" and "offer" not in st)
            if needs_chain and node_down:
                done["deferred"].append(tid)
                continue
            try:
                what = self._recover_one(tid, st, enqueue)
            except Transient as exc:
                log.warning("task %s: recovery deferred: %s", tid, exc)
                node_down = True
                done["deferred"].append(tid)
                continue
            except Exception:  # one damaged job does not stop the others' recovery
                log.exception("task %s: recovery deferred", tid)
                done["deferred"].append(tid)
                continue
            if what is not None:
                done[what].append(tid)
                if what in ("submitted", "closed"):
                    continue  # _close pruned it
            if phase in FINISHED and any((self.job_dir(tid) / p).exists() for p in PRUNED):
                self._prune(tid)
                done["pruned"].append(tid)
        return done

    def _recover_one(
        self, tid: int, st: dict[str, Any], enqueue: Callable[[int, str], None] | None
    ) -> str | None:
        """What ``recover`` did with one job (None: nothing on chain to reconcile)."""
        phase = st.get("phase")
        if phase == "failed" and "offer" not in st:  # abandonOffer not confirmed
            self._report_failure(tid)
            return "reported"
        if phase in FINISHED:
            return None
        settled = self._settle(tid, st)
        if settled is not None:
            return settled
        if phase not in (*IN_HAND, OFFERED):  # none (rebuilt) or not a phase this daemon writes
            self._save(tid, phase="accepted", reason="job state rebuilt from the chain")
        if enqueue is not None:
            enqueue(tid, self.address)
        return "queued"

    def _report_failure(self, task_id: int) -> dict[str, Any]:
        """Give the task back on chain (TMC ``abandonOffer``: the offer becomes Failed and the
        slot opens for the requester to re-allocate), so neither the worker nor the task is
        held until the deadline."""
        reason = self._state(task_id).get("reason", "")
        out = {"task_id": task_id, "status": "failed", "reason": reason}
        try:
            self._transact("abandonOffer", task_id)
        except Transient:
            raise
        except ContractError as exc:  # e.g. the task was closed meanwhile: nothing to give back
            with chain_call(f"reading the offer of task {task_id}"):
                now = OfferState(self.platform.tmc.offer(task_id, self.address)["state"])
            cid = self._state(task_id).get("cid")
            if now in (OfferState.SUBMITTED, OfferState.REVIEWED) and cid:
                # a submitOutcome whose receipt wait gave up was mined after all
                self._close(task_id, phase="submitted", offer=now.name.lower())
                return {"task_id": task_id, "status": "submitted", "cid": cid}
            log.warning("task %s: giving the failed job back refused: %s", task_id, exc)
            self._save(task_id, offer=f"not abandoned: {exc.name}")  # recover: nothing to redo
            return out | {"offer": f"not abandoned: {exc.name}"}
        self._save(task_id, offer="failed")
        return out | {"offer": "failed"}

    def publish_outcome(self, task_id: int) -> dict[str, Any]:
        """Upload the plaintext files of this worker's submitted outcome of ``task_id`` (a
        sealed outcome's weights become public here, so it can be shared as an MMC model);
        ``{cid, env, domain}`` for ``POST /models``. LookupError when no outcome was submitted."""
        st = self._state(task_id)
        if st.get("phase") != "submitted" or not st.get("cid"):
            raise LookupError(
                f"task {task_id}: this worker submitted no outcome on this chain "
                f"(job state: {st.get('phase', 'none')}, {self.job_dir(task_id)})"
            )
        # nothing goes public before the MMC would list it: a sealed outcome stays sealed while
        # its review is pending, and for good once rejected ("A listed model is no outcome")
        with chain_call(f"reading the verdict on the outcome of task {task_id}"):
            _, _, verdict = self.platform.tmc.outcome_of(st["cid"])
        if verdict != Verdict.ACCEPTED:
            raise LookupError(
                f"task {task_id}: the requester has not accepted this outcome (verdict "
                f"{verdict.name.lower()}): only an accepted outcome can be shared as a model"
            )
        model_dir = jobs.run_dir(self.job_dir(task_id)) / st.get("model", "model")
        try:
            publish_model(self.store, st["cid"], model_dir)
        except STORE_OUTAGES as exc:
            raise Transient(str(exc)) from exc
        card = json.loads((model_dir / "model.json").read_text())
        return {
            "cid": st["cid"],
            "env": card.get("env", {}),
            "domain": int(self.platform.tmc.task(task_id)["domain"]),
        }

    def _fetch_spec(self, task_id: int, cid: str) -> TrainingSpec | SpecError:
        """The verified spec ``cid``, or the SpecError saying why it cannot be trained. The
        CID is the task's on-chain description, any text its requester wrote (100 KB, say):
        a reason names it cut to :data:`SHOWN_CID_CHARS`, not echoed whole into state.json,
        the logs and the decline."""
        shown = repr(cid)
        if len(shown) > SHOWN_CID_CHARS:
            shown = f"{shown[:SHOWN_CID_CHARS]}... ({len(cid)} characters)"
        try:
            raw = self.store.get(cid, max_size=MAX_SPEC_BYTES)
        except STORE_OUTAGES as exc:  # down, or a node that gave up finding it in time
            raise Transient(f"cannot fetch task spec {shown}: {exc}") from exc
        except NotFound as exc:
            return SpecNotFound("spec", f"task spec {shown}: {exc}")
        except StoreError as exc:  # bad CID, mismatch, too large, garbled answer
            return SpecError("spec", f"task spec {shown}: {exc}")
        except Exception as exc:  # noqa: BLE001 - a store's own bug: the offer is still answered
            log.exception("task %s: reading task spec %s failed", task_id, shown)
            return SpecError("spec", f"task spec {shown}: {type(exc).__name__}: {exc}")
        try:
            return TrainingSpec.from_json(raw)
        except SpecError as exc:
            return exc

    def _train(self, task_id: int, spec: TrainingSpec, *, deadline: int) -> Path:
        """Fetch the job's models, then train until the spec's budget or DEADLINE_MARGIN_S
        before the deadline, whichever comes first (the fetches' time comes off the training
        time, not off the margin). A start counts against MAX_STARTS_WITHOUT_PROGRESS before
        the fetches (a process killed for memory while loading experts dies there too), and is
        taken back when they fail for a store outage: that is not a process dying. Nor is a
        start whose process died with the whole platform (``start_session`` differs from this
        daemon's), nor one the daemon was asked to stop during (:meth:`note_stop`): only
        deaths of the job's own daemon count."""
        st = self._state(task_id)
        starts = _count(st, "starts_without_progress")
        if starts and self._last_start_not_a_death(task_id, st):
            starts -= 1  # the last start died with the platform or was stopped, not alone
        if starts >= MAX_STARTS_WITHOUT_PROGRESS:
            raise JobKeepsDying(
                f"training was started {starts} times and its process died each time before "
                f"getting past step {st.get('resumed_from_step', 0)} (killed for memory?)"
            )
        start_id = uuid.uuid4().hex
        self._running = (task_id, start_id)  # a stop from here on ends this start
        try:
            # an older start's STOP_MARK names another start: left, never removed here (a stop
            # recorded from now on would be removed with it)
            self._save(task_id, starts_without_progress=starts + 1, start_session=self.session,
                       start_id=start_id)
            return self._train_started(task_id, spec, starts, deadline=deadline)
        finally:
            self._running = None

    def _last_start_not_a_death(self, task_id: int, st: dict[str, Any]) -> bool:
        """Whether the last recorded start ended without its process dying alone: it died
        with the whole platform (another :func:`daemon_session`), or the daemon was asked to
        stop during it (its STOP_MARK names it)."""
        if st.get("start_session", self.session) != self.session:
            return True
        start = st.get("start_id")
        if not isinstance(start, str) or not start:
            return False
        try:
            mark = json.loads((self.job_dir(task_id) / STOP_MARK).read_text())
        except (OSError, ValueError, RecursionError):
            return False
        return isinstance(mark, dict) and mark.get("start") == start

    def note_stop(self, how: str) -> int | None:
        """The daemon was asked to stop (Celery's warm or cold shutdown on SIGTERM, SIGINT,
        SIGQUIT: ``systemctl stop``, ``docker stop``, Ctrl-C): record that the training start
        running now ends by a stop, so the next start does not count it as a death (under
        systemd, or as PID 1 of a container, every restart has the same
        :func:`daemon_session`). A SIGKILL or the OOM killer leaves no record and still
        counts. Runs in the signal handler: writes STOP_MARK only, never raises; returns the
        task id of the start marked, or None when no training start runs."""
        running = self._running
        if running is None or self._stop_noted == running[1]:
            return running[0] if running is not None else None
        task_id, start_id = running
        self._stop_noted = start_id
        mark = self.job_dir(task_id) / STOP_MARK
        tmp = mark.with_name(f"{STOP_MARK}.{os.getpid()}.tmp")
        try:
            with tmp.open("w") as fh:  # on disk before a SIGKILL that may follow the SIGTERM
                fh.write(json.dumps({"start": start_id, "how": how, "at": self.clock(),
                                     "pid": os.getpid()}))
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, mark)
        except OSError as exc:
            log.error("task %s: cannot record the stop (%s): %s", task_id, how, exc)
            return None
        log.warning("task %s: stop requested (%s) while training: this start is not counted "
                    "as a death", task_id, how)
        return task_id

    def _train_started(
        self, task_id: int, spec: TrainingSpec, starts: int, *, deadline: int
    ) -> Path:
        """``_train`` once the start is counted: fetch the job's models, then train."""
        try:
            experts = self._fetch_experts(task_id, spec)
            walls_cae = self._fetch_walls_cae(task_id, spec)
        except Transient:
            self._save(task_id, starts_without_progress=starts)
            raise
        left_min = (deadline - self.clock() - DEADLINE_MARGIN_S) / 60.0
        if left_min <= 0:
            raise RuntimeError(f"task {task_id}: deadline {deadline} leaves no time to train")

        def first(step: int) -> None:
            st = self._state(task_id)
            before = _count(st, "resumed_from_step") if "resumed_from_step" in st else None
            moved = {"starts_without_progress": 1} if before is not None and step > before else {}
            self._save(task_id, first_step_at=self.clock(), resumed_from_step=step, **moved)
            if self.on_first_step is not None:
                self.on_first_step(task_id, step)

        curve = LiveCurve.for_job(spec, left_min * 60.0)  # the gateway keeps 5,000 points

        def progress(point: dict[str, Any]) -> None:
            if curve.keep(point):
                self._post_progress(task_id, point)

        model_dir, _ = jobs.run_job(
            spec,
            self.job_dir(task_id),
            minutes_left=left_min,
            checkpoint_every=self.checkpoint_every,
            checkpoint_interval_s=self.checkpoint_interval_s,
            on_progress=progress,
            on_first_step=first,
            experts=experts,
            walls_cae=walls_cae,
        )
        held = curve.last()
        if held is not None:  # the curve ends where the run did
            self._post_progress(task_id, held)
        return model_dir

    def _fetch_experts(self, task_id: int, spec: TrainingSpec) -> dict[str, Path]:
        """The spec's expert models, verified, in the job directory (kept for a resume);
        ExpertFetchError (the job fails naming the CID) or Transient (store down)."""
        demo = spec.demonstration()  # the experts the run can pick (QoS weight > 0)
        if demo is None:
            return {}
        try:
            dirs = fetch_experts(
                self.store, demo.experts, self.job_dir(task_id), max_weights=self.max_expert_bytes,
                cache=self.cache,
            )
        except STORE_OUTAGES as exc:
            raise Transient(f"cannot fetch the task's expert models: {exc}") from exc
        self._save(task_id, experts=list(demo.experts))
        return dirs

    def _fetch_walls_cae(self, task_id: int, spec: TrainingSpec) -> Path | None:
        """The spec's walls CAE (``observation.walls_embedding``), verified, in the job
        directory; ExpertFetchError names the CID, Transient if the store is down."""
        ref = spec.observation.walls_embedding
        if ref is None:
            return None
        try:
            return fetch_walls_cae(
                self.store, ref, self.job_dir(task_id), max_weights=self.max_expert_bytes,
                cache=self.cache,
            )
        except STORE_OUTAGES as exc:
            raise Transient(f"cannot fetch the task's walls CAE: {exc}") from exc

    def _transact(self, fn: str, *args: Any) -> Any:
        with chain_call(fn):
            return self.platform.tmc.transact(fn, *args, sender=self.address)

    def _post_progress(self, task_id: int, point: dict[str, Any]) -> None:
        """Hand ``point`` to the progress sender (:mod:`workers.daemon.progress_sender`):
        training never waits on the gateway, whatever it answers or however slowly."""
        if self.gateway is None:
            return
        if self._progress is None or self._progress.gateway is not self.gateway:
            self._progress = ProgressSender(self.gateway)
        self._progress.put(task_id, point)

    def _flush_progress(self, task_id: int, wait_s: float) -> None:
        """Give the task's queued points up to ``wait_s`` to reach the gateway (before the
        outcome: the curve is complete when the model is); best effort."""
        if self._progress is not None:
            self._progress.flush(task_id, wait_s)

    def _drop_progress(self, task_id: int) -> None:
        if self._progress is not None:
            self._progress.drop(task_id)


def _count(state: dict[str, Any], key: str) -> int:
    """A counter of ``state.json``; 0 when it is not a count (a damaged or hand-edited file
    must not fail the job)."""
    v = state.get(key, 0)
    return v if isinstance(v, int) and not isinstance(v, bool) and v >= 0 else 0


def _task_dir_name(name: str) -> bool:
    """Whether a job directory's name is a task id as ``job_dir`` writes it."""
    return name.isascii() and name.isdigit() and name == str(int(name))
