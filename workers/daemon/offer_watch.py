"""The chain offer watcher of a worker daemon: it learns this worker's offers from the chain,
not only from the broker.

The gateway's indexer enqueues ``drlaas.handle_offer`` on ``worker.<address>`` when it sees a
``TaskOffered`` event, but a shared broker is no source of truth: any worker holding its
credentials can consume or purge another worker's queue, and a broker restarted without
persistence loses its messages. The chain is ("Nobody has to be trusted"), so every
``DRLAAS_WORKER_OFFER_POLL_S`` seconds (default :data:`DEFAULT_POLL_S`, 0 disables) the
watcher reads the TMC's ``TaskOffered`` events for this worker (``worker`` is an indexed
topic: the node filters them) from the last block it scanned, in ranges of at most
:data:`BLOCK_RANGE` blocks. Its cursor is ``<worker data>/offer_watch/<chain identity>.json``
(written atomically): a restart rescans only :data:`REORG_OVERLAP` blocks; a first start, or a
cursor older than the acceptance window, starts at the first block of that window (found by
bisection over at most :data:`MAX_BACKFILL_BLOCKS` blocks): an older offer has expired.

An offer found is enqueued exactly as the indexer would (``tasks.make_on_offer``: same
queue, same idempotent key ``offer:<task>:<worker>``) when, at a tick:

* the chain still holds it as ``Offered`` to this worker, not past its expiry;
* the daemon has no job directory for it, or one in phase ``offered`` that no ``handle_offer``
  is running for and that has not changed for :data:`DELIVERY_GRACE_S` (a check that failed
  outside the Celery retries, a retry message lost with the broker); a directory of another
  task under that id (the chain lost blocks) counts as none;
* the daemon is idle (no ``handle_offer`` running) and has been for the grace, and the watcher
  saw the offer at least the grace ago: the solo pool runs one job at a time, so an offer's
  message may wait in the queue behind a job being trained, and an idle daemon consumes a
  waiting message within seconds: an offer still without a job then was not delivered;
* the watcher enqueued this offer (task id and expiry) fewer than :data:`MAX_ENQUEUES` times;
  an offer it enqueued stays followed, and is enqueued again when, a grace after, the daemon
  still has no job for it (its message was taken from the queue again: a thief on the broker).

Such an offer is logged (WARNING, "not delivered by the broker") and counted
(``drlaas_worker_offers_found_on_chain_total``). A message of the broker arriving as well is a
duplicate, which the handler answers idempotently (the solo pool runs it after the first:
the offer is then accepted, declined or submitted on chain, and the job says so). A node that
is down fails the tick (logged, retried with backoff, never raised out of the thread); a log
entry or an offer the node answers with wrong types is logged and skipped.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from celery.signals import task_postrun, task_prerun
from eth_utils import keccak

from backend.chain.addresses import checksum
from backend.chain.platform import OfferState
from workers.daemon.handler import OFFERED, node_unreachable

log = logging.getLogger(__name__)

ENV_POLL = "DRLAAS_WORKER_OFFER_POLL_S"
#: Seconds between two reads of the chain (``DRLAAS_WORKER_OFFER_POLL_S``; 0 disables).
DEFAULT_POLL_S = 15.0
#: Longest wait between ticks while the node fails (the poll interval doubles up to it).
MAX_BACKOFF_S = 600.0
#: Blocks per ``eth_getLogs`` request (public nodes refuse wide ranges).
BLOCK_RANGE = 2_000
#: Blocks scanned per tick at most; the rest waits for the next ticks.
MAX_BLOCKS_PER_TICK = 50 * BLOCK_RANGE
#: Blocks before the head a first scan may go back at most (looking for the acceptance window).
MAX_BACKFILL_BLOCKS = 100_000
#: Blocks scanned again below the cursor at each tick (a reorganised chain moves events).
REORG_OVERLAP = 16
#: Seconds an offer must have been seen, and the daemon idle, before the broker is deemed not
#: to have delivered it (the indexer's own polling and confirmations take a few seconds).
DELIVERY_GRACE_S = 60.0
#: Times one offer is enqueued at most (a message taken again and again from our queue is a
#: broker someone else consumes: logged as an error when the last try was taken too).
MAX_ENQUEUES = 3
#: Offers followed at once at most (a node flooding us with events cannot fill the memory).
MAX_PENDING = 1_000
#: Seconds an offer stays followed when the node never answers it sensibly.
MAX_PENDING_AGE_S = 86_400.0
#: The watcher's files, under the worker's data directory.
WATCH_DIR = "offer_watch"


def poll_interval_from_env(environ: Mapping[str, str] | None = None) -> float:
    """``DRLAAS_WORKER_OFFER_POLL_S`` in seconds (DEFAULT_POLL_S when unset; 0: no watcher);
    ValueError naming the variable for anything but a finite number >= 0."""
    from workers.daemon.tasks import env_seconds  # the daemon's other variables' rule

    return env_seconds(os.environ if environ is None else environ, ENV_POLL, DEFAULT_POLL_S,
                       note=" (0 disables the chain offer watcher)")


# -- which offers this process is handling now (Celery's solo pool: its main thread) -------
_in_flight: dict[int, int] = {}
_in_flight_lock = threading.Lock()
_idle_since = time.monotonic()


def _offer_task_id(task: Any, args: Any) -> int | None:
    from workers.daemon.tasks import TASK_NAME

    if getattr(task, "name", None) != TASK_NAME or not args:
        return None
    try:
        return int(args[0])
    except (TypeError, ValueError):
        return None


@task_prerun.connect(weak=False)
def _handling_starts(task: Any = None, args: Any = None, **_: Any) -> None:
    tid = _offer_task_id(task, args)
    if tid is not None:
        with _in_flight_lock:
            _in_flight[tid] = _in_flight.get(tid, 0) + 1


@task_postrun.connect(weak=False)
def _handling_ends(task: Any = None, args: Any = None, **_: Any) -> None:
    global _idle_since
    tid = _offer_task_id(task, args)
    if tid is not None:
        with _in_flight_lock:
            left = _in_flight.get(tid, 0) - 1
            if left > 0:
                _in_flight[tid] = left
            else:
                _in_flight.pop(tid, None)
            _idle_since = time.monotonic()


def handling() -> tuple[frozenset[int], float]:
    """(task ids whose ``handle_offer`` runs in this process now, seconds since the last one
    ended, or since this module was loaded)."""
    with _in_flight_lock:
        return frozenset(_in_flight), time.monotonic() - _idle_since


# -- the watcher ---------------------------------------------------------------------------
class BadAnswer(ValueError):
    """The node answered with something that is not what was asked (wrong types)."""


def _int(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise BadAnswer(f"{what}: expected a non-negative integer, got {type(value).__name__}")
    return value


def _word(value: Any, what: str) -> bytes:
    if isinstance(value, str):
        try:
            value = bytes.fromhex(value.removeprefix("0x"))
        except ValueError:
            raise BadAnswer(f"{what}: not hex") from None
    if not isinstance(value, (bytes, bytearray)) or len(value) != 32:
        raise BadAnswer(f"{what}: expected 32 bytes, got {type(value).__name__}")
    return bytes(value)


def event_topic(abi: list[dict[str, Any]], name: str) -> bytes:
    """topic0 of the event ``name`` of a contract ABI: keccak256 of its signature."""
    for entry in abi:
        if entry.get("type") == "event" and entry.get("name") == name:
            types = ",".join(i["type"] for i in entry.get("inputs", ()))
            return keccak(text=f"{name}({types})")
    raise LookupError(f"no event {name} in the ABI")


class OfferWatcher:
    """Finds this worker's offers on chain and enqueues those the broker did not deliver.

    ``handler`` is the daemon's :class:`~workers.daemon.handler.OfferHandler` (its account,
    platform and job directories are read, never written), ``enqueue`` the indexer's
    ``on_offer(task_id, worker)``. ``handling`` says what this process handles now and for
    how long it has been idle (default: :func:`handling`, fed by Celery's signals); ``clock``
    is the wall clock (when an offer was first seen is kept across restarts)."""

    def __init__(
        self,
        handler: Any,
        enqueue: Callable[[int, str], None],
        *,
        poll_s: float = DEFAULT_POLL_S,
        grace_s: float = DELIVERY_GRACE_S,
        handling: Callable[[], tuple[frozenset[int], float]] = handling,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.handler = handler
        self.enqueue = enqueue
        self.poll_s = poll_s
        self.grace_s = grace_s
        self._handling = handling
        self.clock = clock
        self.address = checksum(handler.address)
        self.worker_topic = bytes(12) + bytes.fromhex(self.address[2:])
        tmc = handler.platform.tmc
        self.tmc_address = checksum(tmc.address)
        self.topic = event_topic(tmc.contract.abi, "TaskOffered")
        self.path: Path | None = None  # <data>/offer_watch/<chain identity>.json, at 1st tick
        self.block: int | None = None  # last block scanned
        self.pending: dict[int, float] = {}  # task id -> when first seen (clock)
        self.enqueued: dict[int, int] = {}  # task id -> offer expiry enqueued
        self.attempts: dict[int, int] = {}  # task id -> times enqueued (for that expiry)
        self.found = 0  # offers enqueued because the broker had not delivered them
        self.errors = 0  # ticks that failed (node down, garbage where a number was due)

    # -- the cursor on disk ----------------------------------------------------------------
    def _load(self) -> None:
        """Read the cursor (the chain identity names it: one node call, hence at a tick)."""
        identity = self.handler.platform.identity
        self.path = Path(self.handler.data_dir) / WATCH_DIR / f"{identity}.json"
        try:
            doc = json.loads(self.path.read_text())
        except FileNotFoundError:
            return
        except (OSError, ValueError, RecursionError) as exc:
            log.warning("offer watcher: cursor %s unreadable (%s): scanning the acceptance "
                        "window again", self.path, exc)
            return
        if not isinstance(doc, dict):
            return
        block = doc.get("block")
        if isinstance(block, int) and not isinstance(block, bool) and block >= 0:
            self.block = block
        for name, into, kind in (("enqueued", self.enqueued, int),
                                 ("attempts", self.attempts, int),
                                 ("pending", self.pending, (int, float))):
            part = doc.get(name)
            for key, value in (part.items() if isinstance(part, dict) else ()):
                if (str(key).isascii() and str(key).isdigit() and isinstance(value, kind)
                        and not isinstance(value, bool) and len(into) < MAX_PENDING):
                    into[int(key)] = value

    def _save(self) -> None:
        assert self.path is not None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        doc = {"block": self.block, "enqueued": {str(k): v for k, v in self.enqueued.items()},
               "attempts": {str(k): v for k, v in self.attempts.items()},
               "pending": {str(k): v for k, v in self.pending.items()}}
        tmp = self.path.with_name(f"{self.path.name}.tmp")
        with tmp.open("w") as fh:
            fh.write(json.dumps(doc))
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, self.path)

    # -- one tick --------------------------------------------------------------------------
    def tick(self) -> list[int]:
        """Scan the blocks since the cursor, then enqueue the offers due; the task ids
        enqueued. Raises when the node fails (the caller retries later)."""
        if self.path is None:
            self._load()
        chain = self.handler.platform.chain
        head = _int(chain.w3.eth.block_number, "eth_blockNumber")
        start = self._first_block(head)
        end = min(head, start + MAX_BLOCKS_PER_TICK - 1)
        lo = start
        while lo <= end:
            hi = min(end, lo + BLOCK_RANGE - 1)
            for tid in self._offers_in(lo, hi):
                if tid not in self.pending and len(self.pending) < MAX_PENDING:
                    self.pending[tid] = self.clock()
                elif tid not in self.pending:
                    log.warning("offer watcher: %d offers followed already, task %s left for "
                                "a later scan", MAX_PENDING, tid)
            self.block = hi
            self._save()
            lo = hi + 1
        return self._enqueue_due()

    def _first_block(self, head: int) -> int:
        """Where this tick's scan begins: a little below the cursor, or at the first block of
        the acceptance window when there is no cursor, it is older than that window, or the
        chain went back under it (a chain file that lost blocks). A cursor close to the head
        needs no look at the window (the bisection is for first starts and long stops)."""
        if self.block is not None and self.block <= head and head - self.block <= BLOCK_RANGE:
            return max(0, self.block + 1 - REORG_OVERLAP)
        window = self._window_start(head)
        if self.block is None or self.block > head or self.block < window:
            return window
        return max(window, self.block + 1 - REORG_OVERLAP)

    def _window_start(self, head: int) -> int:
        """The first block of the last acceptance window (``TMC.acceptWindow`` seconds before
        the head's time), at most MAX_BACKFILL_BLOCKS back: an earlier offer has expired."""
        eth = self.handler.platform.chain.w3.eth
        lo = max(0, head - MAX_BACKFILL_BLOCKS)
        window = _int(self.handler.platform.tmc.call("acceptWindow"), "acceptWindow")
        since = _int(eth.get_block(head)["timestamp"], "block timestamp") - window
        if _int(eth.get_block(lo)["timestamp"], "block timestamp") >= since:
            return lo
        hi = head  # timestamp(lo) < since <= timestamp(hi)
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if _int(eth.get_block(mid)["timestamp"], "block timestamp") >= since:
                hi = mid
            else:
                lo = mid
        return hi

    def _offers_in(self, lo: int, hi: int) -> list[int]:
        """Task ids of this worker's TaskOffered events in blocks lo..hi (the node filters by
        the indexed ``worker`` topic; each entry is checked again here)."""
        raw = self.handler.platform.chain.w3.eth.get_logs({
            "address": self.tmc_address, "fromBlock": lo, "toBlock": hi,
            "topics": [self.topic, None, self.worker_topic],  # type: ignore[list-item]
        })
        if not isinstance(raw, list):
            raise BadAnswer(f"eth_getLogs: expected a list, got {type(raw).__name__}")
        out = []
        for entry in raw:
            try:
                tid = self._task_of(entry, lo, hi)
            except (BadAnswer, KeyError, TypeError, AttributeError) as exc:
                log.warning("offer watcher: log entry of blocks %d-%d skipped: %s", lo, hi, exc)
                continue
            if tid is not None:
                out.append(tid)
        return out

    def _task_of(self, entry: Any, lo: int, hi: int) -> int | None:
        topics = list(entry["topics"])
        if len(topics) != 3 or _word(topics[0], "topic0") != self.topic:
            return None  # not a TaskOffered event
        if _word(topics[2], "worker topic") != self.worker_topic:
            return None  # another worker's (a node that ignored the filter)
        if checksum(str(entry["address"])) != self.tmc_address:
            return None
        block = _int(entry["blockNumber"], "blockNumber")
        if not lo <= block <= hi:
            raise BadAnswer(f"block {block} outside the range asked")
        tid = int.from_bytes(_word(topics[1], "taskId topic"), "big")
        if not 0 < tid < 2**64:
            raise BadAnswer(f"task id {tid} out of range")
        return tid

    def _enqueue_due(self) -> list[int]:
        """Enqueue the followed offers that are due (see the module docstring); drop those the
        chain no longer offers to this worker or that the daemon has in hand."""
        platform = self.handler.platform
        now = _int(platform.chain.now(), "latest block timestamp")
        for tid in [t for t, e in self.enqueued.items() if e < now]:  # expired: forget them
            del self.enqueued[tid]
            self.attempts.pop(tid, None)
        running, idle_for = self._handling()
        idle = not running and idle_for >= self.grace_s
        clock = self.clock()
        done: list[int] = []
        try:
            for tid, seen in sorted(self.pending.items()):
                if clock - seen > MAX_PENDING_AGE_S:
                    self.pending.pop(tid)
                    continue
                try:
                    offer = platform.tmc.offer(tid, self.address)
                    state = OfferState(_int(int(offer["state"]), "offer state"))
                    expiry = _int(offer["expiry"], "offer expiry")
                    answered = (state != OfferState.OFFERED or expiry < now
                                or self._tries(tid, expiry) >= MAX_ENQUEUES)
                    job = None if answered else self._job(tid, running)
                except Exception as exc:
                    if node_unreachable(exc):
                        raise
                    log.warning("offer watcher: the offer of task %s skipped: %s: %s", tid,
                                type(exc).__name__, exc)
                    continue
                if answered or job == "handled":
                    self.pending.pop(tid)  # answered, expired, enqueued enough, or in hand
                    if answered and state == OfferState.OFFERED and expiry >= now:  # enough
                        log.error(
                            "task %s: the offer's message was taken from %s's queue %d times "
                            "without reaching this daemon: is another consumer on the broker "
                            "reading this worker's queue? Not enqueued again", tid,
                            self.address, MAX_ENQUEUES)
                    continue
                if job == "wait" or tid in running or not idle or clock - seen < self.grace_s:
                    continue
                self.enqueue(tid, self.address)  # raises when the broker is down: next tick
                self.pending[tid] = clock  # followed on: enqueued again if taken again
                self.attempts[tid] = self._tries(tid, expiry) + 1
                self.enqueued[tid] = expiry
                self.found += 1
                done.append(tid)
                log.warning(
                    "task %s: offer to %s found on chain, not delivered by the broker (no job "
                    "for it %.0f s after it was seen, the daemon idle): enqueued on its queue",
                    tid, self.address, clock - seen)
        finally:
            self._save()
        return done

    def _tries(self, tid: int, expiry: int) -> int:
        """Times this offer (``tid`` with this ``expiry``) was enqueued by the watcher."""
        return self.attempts.get(tid, 0) if self.enqueued.get(tid) == expiry else 0

    def _job(self, tid: int, running: frozenset[int]) -> str | None:
        """What the daemon has of task ``tid``: None (no job directory, or one of another
        task under that id), ``handled`` (a job past ``offered``), ``wait`` (``offered`` and
        being handled, or changed within the grace), ``stuck`` (``offered``, nobody on it).
        Reads only: the handler owns the files."""
        f = self.handler.job_dir(tid) / "state.json"
        try:
            st = json.loads(f.read_text())
            changed = f.stat().st_mtime
        except FileNotFoundError:
            return None
        except (OSError, ValueError, RecursionError):
            return "handled"  # unreadable: recovery's business, not the watcher's
        if not isinstance(st, dict):
            return "handled"
        record = st.get("task")
        if isinstance(record, dict) and "deadline" in record:
            task = self.handler.platform.tmc.task(tid)
            if (str(record.get("requester", "")).lower() != str(task["requester"]).lower()
                    or record.get("deadline") != int(task["deadline"])):
                return None  # made for another task under this id: the handler sets it aside
        if st.get("phase") != OFFERED:
            return "handled"
        if tid in running or time.time() - changed < self.grace_s:
            return "wait"
        return "stuck"

    # -- the thread ------------------------------------------------------------------------
    def run(self, stop: threading.Event) -> None:
        """Tick every ``poll_s`` until ``stop`` is set; a failed tick is logged and retried
        after a wait doubling up to MAX_BACKOFF_S. Never raises."""
        wait = 0.0
        failures = 0
        while not stop.wait(wait):
            try:
                self.tick()
                failures = 0
            except Exception as exc:  # noqa: BLE001 - the watcher never stops the daemon
                failures += 1
                self.errors += 1
                what = "chain node unreachable" if node_unreachable(exc) else "failed"
                log.warning("offer watcher: %s (%s: %s); next try in %.0f s", what,
                            type(exc).__name__, exc,
                            min(self.poll_s * 2**failures, MAX_BACKOFF_S))
            wait = min(self.poll_s * 2**failures, MAX_BACKOFF_S)


def start_watcher(
    handler: Any, enqueue: Callable[[int, str], None], poll_s: float | None = None
) -> OfferWatcher | None:
    """Start the watcher of ``handler``'s offers on a daemon thread (``poll_s`` default: the
    environment's); None when it is disabled (0)."""
    poll_s = poll_interval_from_env() if poll_s is None else poll_s
    if poll_s <= 0:
        log.info("offer watcher disabled (%s=0): offers come from the broker only", ENV_POLL)
        return None
    watcher = OfferWatcher(handler, enqueue, poll_s=poll_s)
    stop = threading.Event()
    thread = threading.Thread(target=watcher.run, args=(stop,), name="offer-watch", daemon=True)
    watcher.stop = stop  # type: ignore[attr-defined]
    thread.start()
    return watcher
