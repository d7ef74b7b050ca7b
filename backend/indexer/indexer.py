"""Follow UMC/TMC/MMC events into SQL tables (docs/platform.md, "indexer").

Guarantees:

* resumes from ``index_cursor`` (one row per contract, all advanced together): the cursor's
  ``block_number`` is the last block fully processed and ``log_index`` the last event applied
  in it (-1 if none), so a restart rescans nothing processed and misses nothing after it;
* idempotent on (block, log index): an event already in ``chain_events`` is skipped, so
  re-processing a range (a lost cursor, two pollers) changes nothing; a poller that loses the
  race for a range (the other committed it first) goes on from the winner's cursor;
* a batch of blocks is one database transaction (events, entity rows and cursor together);
* ``confirmations`` blocks are left unprocessed at the head (real nodes may reorganise);
* ``on_offer(task_id, worker)`` is called for every ``TaskOffered`` before the batch commits:
  at-least-once (a crash after the hook repeats it; the job key ``offer:<task>:<worker>``
  makes the job idempotent), never lost. A failing hook rolls the batch back for a retry;
* the content store never holds up an event: a task is indexed ``pending`` and its spec is read
  after the batch (:meth:`Indexer.fill_specs`, within a time budget per poll, with a short find
  timeout, fewest reads first), so a description naming a CID nobody holds costs one short read
  per poll, ``SPEC_TRIES`` in all, instead of stopping every later event; a store that is down
  leaves specs pending for the next poll, never "no spec";
* one event's rows that the database cannot hold (a value out of a column's range, a row that
  violates a constraint) never stop the index: each event is applied in a SAVEPOINT, and such
  an event is kept in ``chain_events`` with its ``error``, without its rows;
* text as anyone's own transaction may write it (the contracts take any bytes as a string)
  never stops the index: bytes that are not UTF-8 decode as U+FFFD (``Chain._decode_logs``;
  a strict decoding failed every poll at that block), NUL is stored as U+FFFD (``_text``);
* a string longer than ``EVENT_TEXT_LIMIT`` (a direct write's ~750 KB description) is cut in
  ``chain_events.args``, marked with how much was cut; the chain keeps it whole;
* a different chain (another ``anchor``: hash of the UMC's deployment block, e.g. a restarted
  embedded chain) wipes the indexed tables instead of mixing two histories;
* a chain that went back under the cursor (a reorg deeper than ``confirmations``, an embedded
  chain file that lost its last blocks in a power cut) is noticed by the hashes of the indexed
  blocks (``index_blocks``): the index is rebuilt, and the offers of the blocks that are still
  the chain's are not handed to ``on_offer`` again;
* a range is written only if the node answered it from one branch: the hash of its last block
  is read before and after ``eth_getLogs`` and each log's ``blockHash`` must be its block's
  (:class:`ChainMoved`; a reorg between the logs and the hashes left the lost branch's events
  indexed under the new branch's hashes, unnoticed for good).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

from hexbytes import HexBytes
from sqlalchemy import delete, func, select, update
from sqlalchemy.exc import DataError, IntegrityError
from sqlalchemy.orm import Session, sessionmaker
from web3.exceptions import BlockNotFound

from backend.chain.platform import OfferState, TaskStatus, WorkerStatus
from backend.chain.qos import mmc_reputation_fixed, rating_fixed, reputation_fixed
from backend.db import models as m
from backend.services.chain import ChainService
from backend.services.specs import load_json_doc, summarize_env
from backend.store import ContentStore, NotFound, StoreUnavailable
from backend.store.cid import CID
from workers.mdrl.trainingspec import MAX_SPEC_BYTES, TRAINING_SPEC_FORMAT, TrainingSpec

log = logging.getLogger(__name__)

OfferHook = Callable[[int, str], None]
HALF = 500_000  # QoS fixed point 0.5: no history yet (backend.chain.qos)
INDEXED_TABLES = (
    m.ProgressPoint,  # not from the chain, but tied to tasks of the wiped chain
    m.ReviewRow,
    m.AllocatedModel,
    m.AllocationRow,
    m.ModelRow,
    m.OutcomeRow,
    m.OfferRow,
    m.TaskRow,
    m.WorkerCounters,
    m.WorkerDomain,
    m.WorkerRow,
    m.Requester,
    m.ChainEvent,
    m.IndexCursor,
    m.IndexBlock,
)
TASK_TYPE_TRAINING, TASK_TYPE_SHARING = 0, 1
KEPT_BLOCK_HASHES = 256  # how far back a chain that went back can be followed block by block
HANDED_OVER = "offers_handed_over"  # IndexMeta: offers up to this block reached on_offer
INT64_MAX = 2**63 - 1
SPEC_TRIES = 3
"""Reads of a task's spec that found nothing before the task is marked ``missing``."""
SPEC_RETRY_S = 60
"""A ``missing`` spec is read again this long after it was marked, then twice as long after
each read that finds nothing, up to ``SPEC_RETRY_MAX_S``: a requester's node that was slow or
offline for a while does not leave its task without a spec for good."""
SPEC_RETRY_MAX_S = 3600
SPEC_FIND_TIMEOUT_S = 2.0
"""How long one spec read may look for an absent CID on an IPFS node (the node's default is 10
s; a spec posted through the gateway is on its own node and is found at once)."""
SPEC_BUDGET_S = 1.0
"""Time one poll spends reading pending specs after its events: a read starts only within it,
so a poll takes at most this plus one read longer than its events."""
SPEC_BATCH = 64
"""Pending tasks one poll looks at, at most."""
UNSTORABLE = (DataError, IntegrityError, ValueError, TypeError, KeyError, ArithmeticError)
"""What an event's own data can make a handler raise, directly or as the ``orig`` of a
SQLAlchemy error (deterministic: retrying never helps); anything else (the database or the store
unreachable, a lock timeout) rolls the batch back."""


class ChainMoved(RuntimeError):
    """The node switched branches while a range was read (its logs and its block hashes are of
    different branches): nothing of the range is written, the next poll reads it again (and
    ``check_continuity`` rebuilds what the switch took back under the cursor)."""


def _noop(task_id: int, worker: str) -> None:
    """Default ``on_offer`` hook: nothing (the worker daemon wiring injects the Celery one)."""


def jsonable(v: Any) -> Any:
    if isinstance(v, bytes | HexBytes):
        return "0x" + bytes(v).hex()
    if isinstance(v, bool):
        return v
    if isinstance(v, int):
        return v if abs(v) < 2**53 else str(v)  # JavaScript clients lose precision above 2^53
    if isinstance(v, list | tuple):
        return [jsonable(x) for x in v]
    if isinstance(v, dict):
        return {k: jsonable(x) for k, x in v.items()}
    return v


class Indexer:
    """Poll the chain for platform events and apply them; see the module docstring."""

    def __init__(
        self,
        service: ChainService,
        sessions: sessionmaker[Session],
        *,
        confirmations: int = 0,
        on_offer: OfferHook | None = None,
        batch_blocks: int = 500,
        store: ContentStore | None = None,
        spec_budget_s: float = SPEC_BUDGET_S,
        spec_find_timeout_s: float = SPEC_FIND_TIMEOUT_S,
        clock: Callable[[], float] = time.time,
    ) -> None:
        if confirmations < 0:
            raise ValueError(f"confirmations must be >= 0, got {confirmations}")
        if batch_blocks < 1:
            raise ValueError(f"batch_blocks must be >= 1, got {batch_blocks}")
        self.service = service
        self.sessions = sessions
        self.confirmations = confirmations
        self.on_offer: OfferHook = on_offer or _noop
        self.batch_blocks = batch_blocks
        self.store = store
        self._spec_store = store.with_find_timeout(spec_find_timeout_s) if store else None
        self.spec_budget_s = spec_budget_s
        self.clock = clock  # when a missing spec is due (tests move it)
        self._poll_lock = threading.Lock()
        self._checked_anchor = False
        p = service.platform
        self._names = {p.umc.address: "UsersManager", p.tmc.address: "TasksManager"}
        self._names[p.mmc.address] = "ModelsManager"

    # -- cursor ---------------------------------------------------------------------------------
    def _anchor(self) -> str:
        with self.service.lock:
            block = self.service.chain.w3.eth.get_block(self.service.deploy_block)
        return "0x" + bytes(block["hash"]).hex()

    def check_anchor(self) -> bool:
        """Wipe the index if it was built from another chain; True if it wiped."""
        anchor = self._anchor()
        with self.sessions() as s:
            row = s.get(m.IndexMeta, "anchor")
            if row is not None and row.value == anchor:
                self._checked_anchor = True
                return False
            wiped = row is not None or s.scalar(select(m.ChainEvent.id).limit(1)) is not None
            if wiped:
                log.warning("indexer: chain anchor changed (%s); rebuilding the index", anchor)
            for table in INDEXED_TABLES:
                s.execute(delete(table))
            s.execute(delete(m.IndexMeta).where(m.IndexMeta.key == HANDED_OVER))
            s.merge(m.IndexMeta(key="anchor", value=anchor))
            s.commit()
        self._checked_anchor = True
        return wiped

    def _block_hash(self, number: int) -> str | None:
        """The chain's hash of block ``number``, None past its head."""
        try:
            with self.service.lock:
                block = self.service.chain.w3.eth.get_block(number)
        except BlockNotFound:
            return None
        return "0x" + bytes(block["hash"]).hex()

    def check_continuity(self) -> int | None:
        """Rebuild the index if the chain went back under the cursor (its block there is another
        one, or there is none): returns the last indexed block still on the chain (whose offers
        are not handed over again), None if the chain did not go back."""
        newest_first = select(m.IndexBlock.block_number, m.IndexBlock.hash).order_by(
            m.IndexBlock.block_number.desc()
        )
        with self.sessions() as s:
            cursor_block = s.execute(newest_first.limit(1)).first()
            if cursor_block is None or self._block_hash(cursor_block[0]) == cursor_block[1]:
                return None
            known = s.execute(newest_first).all()
        kept = next(
            (n for n, h in known[1:] if self._block_hash(n) == h), self.service.deploy_block - 1
        )
        log.warning(
            "indexer: the chain went back: block %d is not the one indexed (chain head %d); "
            "rebuilding the index, blocks up to %d unchanged",
            known[0][0],
            self.service.block_number(),
            kept,
        )
        with self.sessions() as s:
            lost_tasks = select(m.ChainEvent.task_id).where(
                m.ChainEvent.name == "TaskAdded", m.ChainEvent.block_number > kept
            )
            s.execute(delete(m.ProgressPoint).where(m.ProgressPoint.task_id.in_(lost_tasks)))
            for table in INDEXED_TABLES:
                if table is not m.ProgressPoint:  # the curves of tasks still on the chain stay
                    s.execute(delete(table))
            s.merge(m.IndexMeta(key=HANDED_OVER, value=str(kept)))
            s.commit()
        return kept

    def _handed_over(self, s: Session) -> int:
        row = s.get(m.IndexMeta, HANDED_OVER)
        return int(row.value) if row is not None else -1

    def cursor(self) -> tuple[int, int]:
        """(last fully processed block, last applied log index in it); before any poll the
        block before the deployment."""
        with self.sessions() as s:
            rows = s.scalars(select(m.IndexCursor)).all()
        mine = [r for r in rows if self._names.get(r.address or "") == r.contract]
        if len(mine) == len(self._names):
            return min((r.block_number, r.log_index) for r in mine)
        return self.service.deploy_block - 1, -1

    def _save_cursor(self, s: Session, block: int, log_index: int, hashes: dict[int, str]) -> None:
        for address, name in self._names.items():
            s.merge(
                m.IndexCursor(
                    contract=name, address=address, block_number=block, log_index=log_index
                )
            )
        for number, block_hash in hashes.items():
            s.merge(m.IndexBlock(block_number=number, hash=block_hash))
        s.flush()
        oldest_kept = s.scalar(
            select(m.IndexBlock.block_number)
            .order_by(m.IndexBlock.block_number.desc())
            .offset(KEPT_BLOCK_HASHES - 1)
            .limit(1)
        )
        if oldest_kept is not None:
            s.execute(delete(m.IndexBlock).where(m.IndexBlock.block_number < oldest_kept))

    # -- polling --------------------------------------------------------------------------------
    def head(self) -> int:
        return self.service.block_number() - self.confirmations

    def poll(self) -> int:
        """Apply every confirmed event after the cursor, then read pending task specs within
        ``spec_budget_s``; returns how many events were applied."""
        with self._poll_lock:
            if not self._checked_anchor:
                self.check_anchor()
            self.check_continuity()
            applied = 0
            start, _ = self.cursor()
            head = self.head()
            while start < head:
                to = min(head, start + self.batch_blocks)
                try:
                    applied += self._batch(start + 1, to)
                except ChainMoved as exc:  # nothing of the range was written: the next poll
                    log.warning("indexer: the chain reorganised while blocks %d-%d were read "
                                "(%s); reading them again", start + 1, to, exc)
                    break
                except IntegrityError:  # another indexer (gateway) committed the range first
                    done, _ = self.cursor()
                    if done < to:
                        raise
                    log.info("indexer: blocks %d-%d were indexed by another indexer meanwhile",
                             start + 1, to)
                    start = done
                    continue
                start = to
            self.fill_specs()
            return applied

    def fill_specs(self, budget_s: float | None = None) -> int:
        """Read the specs of ``pending`` tasks, fewest reads first (a new task is not queued
        behind CIDs that were not found) and each requester's in turn (one who posts a hundred
        tasks naming CIDs nobody holds, each costing a find timeout, delays another's first
        read by one of them, not a hundred), then of ``missing`` ones whose retry time came,
        starting reads only within ``budget_s`` (default ``spec_budget_s``); returns how many
        specs were read. Each task is updated in its own transaction; a store that is down ends
        the round and leaves the rest as they were."""
        if self._spec_store is None:
            return 0
        now = int(self.clock())
        with self.sessions() as s:
            columns = (m.TaskRow.id, m.TaskRow.description, m.TaskRow.spec_tries,
                       m.TaskRow.spec_state)
            turn = func.row_number().over(partition_by=m.TaskRow.requester,
                                          order_by=(m.TaskRow.spec_tries, m.TaskRow.id))
            queue = (select(*columns, turn.label("turn"))
                     .where(m.TaskRow.spec_state == "pending").subquery())
            pending = s.execute(
                select(queue.c.id, queue.c.description, queue.c.spec_tries, queue.c.spec_state)
                .order_by(queue.c.spec_tries, queue.c.turn, queue.c.id)
                .limit(SPEC_BATCH)
            ).all()
            due = s.execute(
                select(*columns)
                .where(m.TaskRow.spec_state == "missing", m.TaskRow.spec_retry_at <= now)
                .order_by(m.TaskRow.spec_retry_at, m.TaskRow.id)
                .limit(SPEC_BATCH)
            ).all()
        give_up = time.monotonic() + (self.spec_budget_s if budget_s is None else budget_s)
        read = 0
        for task_id, cid, tries, state in [*pending, *due]:
            if time.monotonic() >= give_up:
                break
            try:
                values = self._read_spec(cid, tries, now)
            except (StoreUnavailable, TimeoutError, ConnectionError) as exc:
                log.warning("indexer: task specs stay %s, the store is unavailable: %s",
                            state, exc)
                break
            read += self._set_spec(task_id, values, was=state) == "read"
        return read

    def _read_spec(self, cid: str, tries: int, now: int) -> dict[str, Any]:
        """The columns a read of the spec behind ``cid`` sets (anyone can addTask with any
        document, and the listing and task pages read what is indexed)."""
        assert self._spec_store is not None
        try:
            doc = load_json_doc(
                self._spec_store, cid, max_size=MAX_SPEC_BYTES, fmt=TRAINING_SPEC_FORMAT
            )
            TrainingSpec.from_dict(doc)
        except (StoreUnavailable, TimeoutError, ConnectionError):
            raise
        except NotFound as exc:  # absent, or not found within the find timeout: maybe later
            log.info("indexer: task spec %s not found (read %d): %s", cid, tries + 1, exc)
            if tries + 1 < SPEC_TRIES:
                return {"spec_state": "pending", "spec_tries": tries + 1}
            wait = min(SPEC_RETRY_S * 2 ** (tries + 1 - SPEC_TRIES), SPEC_RETRY_MAX_S)
            return {"spec_state": "missing", "spec_tries": tries + 1, "spec_retry_at": now + wait}
        except Exception as exc:  # not a spec: keep the raw text only
            log.info("indexer: task description %r is not a readable task spec: %s", cid, exc)
            return {"spec_state": "invalid", "spec_tries": tries + 1, "spec_retry_at": None}
        return {"spec": _json_safe(doc), "spec_state": "read", "spec_tries": tries + 1,
                "spec_retry_at": None}

    def _set_spec(self, task_id: int, values: dict[str, Any], was: str = "pending") -> str:
        """Write ``values`` on a task still in state ``was`` (another poller may have read it);
        a spec the database refuses marks the task ``invalid``. Returns the state written."""
        unchanged = (m.TaskRow.id == task_id, m.TaskRow.spec_state == was)
        with self.sessions() as s:
            try:
                s.execute(update(m.TaskRow).where(*unchanged).values(**values))
                s.commit()
                return str(values["spec_state"])
            except Exception as exc:  # NaN/NUL the database refuses arrive wrapped (orig)
                if not _unstorable(exc):
                    raise
                s.rollback()
                log.info("indexer: task %d's spec cannot be stored: %s", task_id, exc)
            s.execute(update(m.TaskRow).where(*unchanged)
                      .values(spec_state="invalid", spec_retry_at=None))
            s.commit()
            return "invalid"

    def _fetch(
        self, from_block: int, to_block: int
    ) -> tuple[list[tuple[dict[str, Any], Any]], dict[int, str]]:
        """The decoded events of the range, and the hashes of their blocks and of ``to_block``
        (read in the same lock: a log and the block it is checked against agree)."""
        chain = self.service.chain
        with self.service.lock:
            tip = self._block_hash(to_block)  # the branch the logs must come from
            raw = chain.w3.eth.get_logs(
                {"address": list(self._names), "fromBlock": from_block, "toBlock": to_block}  # type: ignore[typeddict-item]
            )
            raw = sorted(raw, key=lambda lg: (lg["blockNumber"], lg["logIndex"]))
            out = []
            times: dict[int, int] = {}
            hashes: dict[int, str] = {}
            for lg in raw:
                decoded = chain._decode_logs([lg])
                if not decoded:
                    continue
                b = lg["blockNumber"]
                if b not in times:
                    block = chain.w3.eth.get_block(b)
                    times[b], hashes[b] = int(block["timestamp"]), "0x" + bytes(block["hash"]).hex()
                log_block = lg.get("blockHash")
                if log_block is not None and "0x" + bytes(log_block).hex() != hashes[b]:
                    raise ChainMoved(f"a log of block {b} is of another branch than the block")
                out.append((dict(lg) | {"_time": times[b]}, decoded[0]))
            if tip is None or self._block_hash(to_block) != tip:
                raise ChainMoved(f"block {to_block} changed while its range was read")
            hashes[to_block] = tip
        return out, hashes

    def _batch(self, from_block: int, to_block: int) -> int:
        events, hashes = self._fetch(from_block, to_block)
        offers: list[tuple[int, str]] = []
        applied = 0
        last_index = -1
        with self.sessions() as s:
            handed_over = self._handed_over(s)
            for raw, ev in events:
                block, index = int(raw["blockNumber"]), int(raw["logIndex"])
                if block == to_block:
                    last_index = index
                exists = s.scalar(
                    select(m.ChainEvent.id).where(
                        m.ChainEvent.block_number == block, m.ChainEvent.log_index == index
                    )
                )
                if exists is not None:
                    continue
                args = dict(ev.args)
                event = self._record(s, raw, ev.contract, ev.name, args)
                handler = getattr(self, f"_on_{ev.name}", None)
                if handler is not None:
                    self._apply(s, event, handler, args, block)
                if ev.name == "TaskOffered" and block > handed_over:
                    offers.append((int(args["taskId"]), str(args["worker"])))
                applied += 1
            self._save_cursor(s, to_block, last_index, hashes)
            s.flush()
            for task_id, worker in offers:
                self.on_offer(task_id, worker)  # raising rolls the batch back (retried)
            s.commit()
        return applied

    def _apply(
        self,
        s: Session,
        event: m.ChainEvent,
        handler: Callable[[Session, dict[str, Any], int], None],
        args: dict[str, Any],
        block: int,
    ) -> None:
        """Run ``handler`` in a SAVEPOINT: rows the database cannot hold are dropped with the
        reason on the event (retrying would fail the same way for ever), any other failure
        rolls the batch back."""
        s.flush()  # the event row itself: its failure (two pollers) is the batch's
        try:
            with s.begin_nested():
                handler(s, args, block)
        except Exception as exc:
            orig = getattr(exc, "orig", None)
            if not _unstorable(exc):
                raise
            reason = str(orig if orig is not None else exc).splitlines()[0]
            event.error = _text(f"{type(exc).__name__}: {reason}", 512)
            log.warning(
                "indexer: event %s at block %d log %d kept without its rows: %s",
                event.name,
                event.block_number,
                event.log_index,
                event.error,
            )

    def _record(
        self, s: Session, raw: dict[str, Any], contract: str, name: str, args: dict
    ) -> m.ChainEvent:
        alloc_id = args.get("allocId")
        task_id = args.get("taskId")
        if name == "PaymentCredited" and contract == "ModelsManager":
            alloc_id = args.get("allocId", args.get("taskId"))
            task_id = None
        account = next(
            (args[k] for k in ("worker", "requester", "owner", "account") if k in args), None
        )
        event = m.ChainEvent(
            block_number=int(raw["blockNumber"]),
            log_index=int(raw["logIndex"]),
            tx_hash="0x" + bytes(raw["transactionHash"]).hex(),
            contract=contract,
            name=name,
            args=_bounded_strings(jsonable(args)),
            block_time=raw["_time"],
            task_id=_int64_or_none(task_id),
            model_id=_int64_or_none(args.get("modelId")),
            alloc_id=_int64_or_none(alloc_id),
            account=account,
        )
        s.add(event)
        return event

    # -- UMC ------------------------------------------------------------------------------------
    def _on_WorkerAdded(self, s: Session, a: dict[str, Any], block: int) -> None:
        address = a["worker"]
        s.merge(
            m.WorkerRow(
                address=address,
                worker_id=int(a["id"]),
                domain_mask=str(a["domains"]),
                cpu_cores=a["cpuCores"],
                ram_gb=a["ramGb"],
                gpu_series=a["gpuSeries"],
                status=WorkerStatus.ACTIVE.name.lower(),
                assigned=0,
                accepted=0,
                completed=0,
                rating_sum=0,
                rating_count=0,
                reputation=HALF,
                rating=HALF,
                sharing_reputation=HALF,
                sharing_rating=HALF,
                block_number=block,
            )
        )
        s.flush()
        for d in _bits(int(a["domains"])):
            s.merge(m.WorkerDomain(address=address, domain=d))

    def _on_RequesterAdded(self, s: Session, a: dict[str, Any], block: int) -> None:
        s.merge(m.Requester(address=a["requester"], block_number=block))

    def _on_RequesterStatusUpdated(self, s: Session, a: dict[str, Any], block: int) -> None:
        """The index lists Active requesters (RequesterAdded); a removed one leaves it."""
        if int(a["status"]) == WorkerStatus.REMOVED:
            row = s.get(m.Requester, a["requester"])
            if row is not None:
                s.delete(row)

    def _on_WorkerStatusUpdated(self, s: Session, a: dict[str, Any], block: int) -> None:
        w = s.get(m.WorkerRow, a["worker"])
        if w is not None:
            w.status = WorkerStatus(int(a["status"])).name.lower()

    def _on_WorkerCapabilitiesUpdated(self, s: Session, a: dict[str, Any], block: int) -> None:
        w = s.get(m.WorkerRow, a["worker"])
        if w is not None:
            w.cpu_cores, w.ram_gb, w.gpu_series = a["cpuCores"], a["ramGb"], a["gpuSeries"]

    def _on_WorkerInfoUpdated(self, s: Session, a: dict[str, Any], block: int) -> None:
        address, task_type = a["worker"], int(a["taskType"])
        s.merge(
            m.WorkerCounters(
                address=address,
                domain=int(a["domain"]),
                task_type=task_type,
                assigned=a["assigned"],
                accepted=a["accepted"],
                completed=a["completed"],
                rating_sum=a["ratingSum"],
                rating_count=a["ratingCount"],
            )
        )
        s.flush()
        w = s.get(m.WorkerRow, address)
        if w is None:
            return
        rows = s.scalars(
            select(m.WorkerCounters).where(
                m.WorkerCounters.address == address, m.WorkerCounters.task_type == task_type
            )
        ).all()
        tot = {
            k: sum(getattr(r, k) for r in rows)
            for k in ("assigned", "accepted", "completed", "rating_sum", "rating_count")
        }
        rep = reputation_fixed(tot["assigned"], tot["accepted"], tot["completed"])  # Eq. 19
        rat = rating_fixed(tot["rating_sum"], tot["rating_count"])  # 7.5.1 rating
        if task_type == TASK_TYPE_TRAINING:
            for k, v in tot.items():
                setattr(w, k, v)
            w.reputation, w.rating = rep, rat
        else:
            w.sharing_reputation, w.sharing_rating = rep, rat

    # -- TMC ------------------------------------------------------------------------------------
    def _on_TaskAdded(self, s: Session, a: dict[str, Any], block: int) -> None:
        task_id = int(a["taskId"])
        s.merge(
            m.TaskRow(
                id=task_id,
                requester=a["requester"],
                domain=int(a["domain"]),
                num_workers=int(a["numWorkers"]),
                reward_wei=str(a["reward"]),
                deadline=int(a["deadline"]),
                min_reputation=a["minReputation"],
                min_rating=a["minRating"],
                min_cpu_cores=a["minCpuCores"],
                min_ram_gb=a["minRamGb"],
                description=_text(a["description"], 512),
                spec=None,  # read after the batch: fill_specs
                spec_state="pending" if _is_cid(str(a["description"])) else "none",
                spec_tries=0,
                status=TaskStatus.OPEN.name.lower(),
                offered=0,
                block_number=block,
                updated_block=block,
            )
        )

    def _offer(self, s: Session, a: dict[str, Any]) -> m.OfferRow | None:
        return s.get(m.OfferRow, (int(a["taskId"]), a["worker"]))

    def _on_TaskOffered(self, s: Session, a: dict[str, Any], block: int) -> None:
        task_id = int(a["taskId"])
        s.merge(
            m.OfferRow(
                task_id=task_id,
                worker=a["worker"],
                state=OfferState.OFFERED.name.lower(),
                qos=_clamp64(a["qos"]),
                expiry=int(a["expiry"]),
                block_number=block,
                updated_block=block,
            )
        )
        t = s.get(m.TaskRow, task_id)
        if t is not None:
            t.offered += 1
            t.updated_block = block

    def _set_offer(self, s: Session, a: dict[str, Any], block: int, state: OfferState) -> None:
        o = self._offer(s, a)
        if o is not None:
            o.state = state.name.lower()
            o.updated_block = block

    def _on_OfferAccepted(self, s: Session, a: dict[str, Any], block: int) -> None:
        self._set_offer(s, a, block, OfferState.ACCEPTED)

    def _on_OfferDeclined(self, s: Session, a: dict[str, Any], block: int) -> None:
        self._set_offer(s, a, block, OfferState.DECLINED)

    def _on_OfferExpired(self, s: Session, a: dict[str, Any], block: int) -> None:
        self._set_offer(s, a, block, OfferState.EXPIRED)

    def _on_OfferFailed(self, s: Session, a: dict[str, Any], block: int) -> None:
        self._set_offer(s, a, block, OfferState.FAILED)

    def _on_OutcomeSubmitted(self, s: Session, a: dict[str, Any], block: int) -> None:
        self._set_offer(s, a, block, OfferState.SUBMITTED)
        s.merge(
            m.OutcomeRow(
                task_id=int(a["taskId"]),
                worker=a["worker"],
                cid=_text(a["cid"], 512),
                block_number=block,
            )
        )

    def _on_OutcomeReviewed(self, s: Session, a: dict[str, Any], block: int) -> None:
        self._set_offer(s, a, block, OfferState.REVIEWED)
        o = s.get(m.OutcomeRow, (int(a["taskId"]), a["worker"]))
        if o is not None:
            o.review, o.accepted = int(a["review"]), bool(a["accepted"])

    def _on_OutcomePaidUnreviewed(self, s: Session, a: dict[str, Any], block: int) -> None:
        """Paid at close, never reviewed: accepted, with no review (not a review of 0)."""
        self._set_offer(s, a, block, OfferState.REVIEWED)
        o = s.get(m.OutcomeRow, (int(a["taskId"]), a["worker"]))
        if o is not None:
            o.review, o.accepted = None, True

    def _on_SlotsCancelled(self, s: Session, a: dict[str, Any], block: int) -> None:
        t = s.get(m.TaskRow, int(a["taskId"]))
        if t is not None:
            t.num_workers = int(a["numWorkers"])
            t.updated_block = block

    def _on_TaskStatusUpdated(self, s: Session, a: dict[str, Any], block: int) -> None:
        t = s.get(m.TaskRow, int(a["taskId"]))
        if t is not None:
            t.status = TaskStatus(int(a["status"])).name.lower()
            t.updated_block = block

    # -- MMC ------------------------------------------------------------------------------------
    def _on_ModelAdded(self, s: Session, a: dict[str, Any], block: int) -> None:
        env = [int(v) for v in a["env"]]
        summary = summarize_env(env)
        s.merge(
            m.ModelRow(
                id=int(a["modelId"]),
                owner=a["owner"],
                domain=int(a["domain"]),
                cid=_text(a["cid"], 512),
                description=_text(a["description"], 2048),
                env=env,
                agents=summary.agents,
                walls_min=summary.walls_min,
                walls_max=summary.walls_max,
                alloc_count=0,
                total_review=0,
                reputation=HALF,
                block_number=block,
            )
        )

    def _on_ModelsRequested(self, s: Session, a: dict[str, Any], block: int) -> None:
        s.merge(
            m.AllocationRow(
                id=int(a["allocId"]),
                requester=a["requester"],
                domain=int(a["domain"]),
                metric=int(a["metric"]),
                num_models=int(a["numModels"]),
                price_wei=str(a["price"]),
                block_number=block,
            )
        )

    def _on_ModelAllocated(self, s: Session, a: dict[str, Any], block: int) -> None:
        s.merge(
            m.AllocatedModel(
                alloc_id=int(a["allocId"]),
                model_id=int(a["modelId"]),
                owner=a["owner"],
                qos=_clamp64(a["qos"]),
            )
        )
        model = s.get(m.ModelRow, int(a["modelId"]))
        if model is not None:
            model.alloc_count += 1
            model.reputation = mmc_reputation_fixed(model.total_review, model.alloc_count)

    def _on_ModelReviewed(self, s: Session, a: dict[str, Any], block: int) -> None:
        alloc_id, model_id, review = int(a["allocId"]), int(a["modelId"]), int(a["review"])
        am = s.get(m.AllocatedModel, (alloc_id, model_id))
        if am is not None:
            am.review = review
        model = s.get(m.ModelRow, model_id)
        if model is not None:
            model.total_review += review
            model.reputation = mmc_reputation_fixed(model.total_review, model.alloc_count)  # Eq. 11


def _bits(mask: int) -> Iterable[int]:
    d = 0
    while mask:
        if mask & 1:
            yield d
        mask >>= 1
        d += 1


class IndexerThread:
    """Runs :meth:`Indexer.poll` every ``interval`` seconds until :meth:`stop`."""

    def __init__(self, indexer: Indexer, interval: float = 1.0) -> None:
        self.indexer = indexer
        self.interval = interval
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="drlaas-indexer", daemon=True)
        self.errors = 0

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.indexer.poll()
            except Exception:  # keep following; the batch was rolled back and is retried
                self.errors += 1
                log.exception("indexer poll failed; retrying in %.1fs", self.interval)
            self._stop.wait(self.interval)

    def stop(self, timeout: float = 10.0) -> None:
        self._stop.set()
        self._thread.join(timeout)


def _unstorable(exc: BaseException) -> bool:
    """Whether ``exc`` is one of ``UNSTORABLE``, itself or as a SQLAlchemy error's ``orig``."""
    return isinstance(exc, UNSTORABLE) or isinstance(getattr(exc, "orig", None), UNSTORABLE)


def _is_cid(text: str) -> bool:
    """Whether a task description names content (a CID) rather than being plain text."""
    try:
        CID.parse(text)
    except Exception:
        return False
    return True


def _clamp64(value: Any) -> int:
    """A uint256 a BIGINT column can hold: larger values (no contract emits them today) are
    clamped, so they still sort last; the event's args keep the exact value."""
    return min(int(value), INT64_MAX)


def _int64_or_none(value: Any) -> int | None:
    """An id a BIGINT column can hold, else None (the event's args keep it)."""
    return int(value) if value is not None and 0 <= int(value) <= INT64_MAX else None


def _text(value: Any, limit: int) -> str:
    """A string of a chain event as every database holds it: NUL, which PostgreSQL text
    refuses (one such event would stop the indexer at its block for good), becomes U+FFFD."""
    return str(value).replace("\x00", "\ufffd")[:limit]


EVENT_TEXT_LIMIT = 2048
"""Characters of one string an indexed event's ``args`` keep: the widest text column of the
index (a model's description). The contracts take a string of any length, so a direct write
could put ~750 KB (its gas allows that much) into one event, which every page of a task's
timeline would then carry; the whole string stays on the chain."""


def _bounded_strings(doc: Any, limit: int = EVENT_TEXT_LIMIT) -> Any:
    """``doc`` with each string longer than ``limit`` cut to it and marked with how much was
    cut, so a reader sees that the index holds less than the chain."""
    if isinstance(doc, str) and len(doc) > limit:
        return f"{doc[:limit]}\u2026 [{len(doc) - limit} more characters on chain]"
    if isinstance(doc, dict):
        return {k: _bounded_strings(v, limit) for k, v in doc.items()}
    if isinstance(doc, list):
        return [_bounded_strings(v, limit) for v in doc]
    return doc


def _json_safe(doc: Any) -> Any:
    """A JSON document as every database holds it: NUL in strings replaced (``_text``),
    non-finite numbers as null (SQLite's JSON and PostgreSQL's jsonb refuse NaN)."""
    if isinstance(doc, dict):
        return {_text(k, 10_000): _json_safe(v) for k, v in doc.items()}
    if isinstance(doc, list):
        return [_json_safe(v) for v in doc]
    if isinstance(doc, str):
        return doc.replace("\x00", "\ufffd")
    if isinstance(doc, float) and not math.isfinite(doc):
        return None
    return doc
