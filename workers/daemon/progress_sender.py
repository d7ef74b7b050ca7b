"""Training progress points posted to the gateway from a thread of their own.

A worker's training loop hands each point over and goes on (:meth:`ProgressSender.put` never
waits): a slow, lagging or hostile gateway can delay the task's live curve, never the training
that the deadline is about. Before the outcome is submitted the job waits a few seconds for its
points to go (:meth:`ProgressSender.flush`), so the curve is complete when the model is.

Points are best effort (``progress.jsonl`` in the job keeps every one): per task at most
:data:`MAX_PENDING_POINTS` wait, the oldest dropped beyond; a point the gateway refuses for
good (409 duplicate step, 422) is dropped with a warning; one it cannot take yet (403
``not_assigned_worker``: its index has not seen our acceptance; a 5xx; the connection down)
is tried again after a pause that doubles up to :data:`MAX_PAUSE_S`.

Which points of a job are posted at all is :class:`LiveCurve`'s choice: the gateway keeps at
most 5,000 per worker and task (409 ``progress_full``), and a spec of tiny updates makes
hundreds a second for up to a week.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from typing import Any

from workers.daemon.gateway import GatewayError

log = logging.getLogger(__name__)

MAX_PENDING_POINTS = 512
"""Points queued per task while the gateway cannot take them: the oldest are dropped beyond."""
FIRST_PAUSE_S = 0.2
MAX_PAUSE_S = 10.0
"""Longest pause between tries while the gateway cannot take points."""
WARNINGS_LOGGED = 3
"""Refused points logged per sender (the rest are counted in ``errors``)."""


FIRST_POINTS = 20
"""Points a job posts at every update before :class:`LiveCurve` thins them."""
LIVE_POINTS = 2_000
"""Points :class:`LiveCurve` lets through by each of its rules (updates, training time): with
FIRST_POINTS, under the gateway's 5,000 per worker and task."""


class LiveCurve:
    """Which progress points of a job go to the gateway. It takes at most 5,000 per worker and
    task and refuses the rest (409 ``progress_full``); a job posted one per update, so a spec
    of one env step per update (~300 updates a second) filled the task's live curve in its
    first 20 s and then posted, and had refused, a point per update for the rest of its
    budget (up to a week): the requester saw nothing of the training after those seconds.
    Now a point goes when it is one of the first FIRST_POINTS, or at every ``stride``-th
    update (the step budget's updates spread over LIVE_POINTS), or in a new slice of
    ``interval_s`` of training time (the time the job may train spread over LIVE_POINTS);
    ``progress.jsonl`` keeps every point. The last point held back is posted after training
    (:meth:`last`), so the curve ends where the run did."""

    def __init__(self, updates: int | None, seconds: float | None) -> None:
        self.stride = max(1, math.ceil(updates / LIVE_POINTS)) if updates else None
        self.interval_s = (seconds / LIVE_POINTS if seconds is not None and seconds > 0
                           and math.isfinite(seconds) else None)
        self._slice: int | None = None
        self._held: dict[str, Any] | None = None

    @classmethod
    def for_job(cls, spec: Any, seconds_left: float) -> LiveCurve:
        """The thinning of a job of ``spec`` (a ``TrainingSpec``) with ``seconds_left`` to
        train (the deadline's)."""
        updates = math.ceil(spec.steps / spec.ppo.batch_steps) if spec.steps else None
        seconds = seconds_left if spec.minutes is None else min(spec.minutes * 60, seconds_left)
        return cls(updates, seconds)

    def keep(self, point: dict[str, Any]) -> bool:
        """Whether ``point`` (``job.progress_point``) is posted; if not, it is held as the
        latest one (:meth:`last`)."""
        update, wall = point.get("update"), point.get("wall_time")
        due = not isinstance(update, int) or update <= FIRST_POINTS
        if self.stride is not None and isinstance(update, int) and update % self.stride == 0:
            due = True
        if self.interval_s is not None and isinstance(wall, int | float) and math.isfinite(wall):
            now = int(wall // self.interval_s)
            if self._slice is None or now > self._slice:
                self._slice, due = now, True  # (the first point of a start opens its slice)
        if self.stride is None and self.interval_s is None:
            due = True
        self._held = None if due else point
        return due

    def last(self) -> dict[str, Any] | None:
        """The latest point held back (None when the last one was posted)."""
        return self._held


class ProgressSender:
    """``put(task_id, point)`` queues; a daemon thread, started on the first point, posts each
    task's points oldest first as ``POST /api/tasks/<id>/progress``."""

    def __init__(self, gateway: Any) -> None:
        self.gateway = gateway
        self.errors = 0
        """Points the gateway refused for good, or attempts that failed (logged up to
        :data:`WARNINGS_LOGGED`)."""
        self._queues: dict[int, deque[dict[str, Any]]] = {}
        self._sending: int | None = None  # the task whose point is being posted
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None

    def put(self, task_id: int, point: dict[str, Any]) -> None:
        """Queue ``point`` for ``task_id``; returns at once."""
        with self._cond:
            queue = self._queues.setdefault(task_id, deque(maxlen=MAX_PENDING_POINTS))
            queue.append(point)
            if self._thread is None:
                self._thread = threading.Thread(
                    target=self._run, name="progress-sender", daemon=True
                )
                self._thread.start()
            self._cond.notify_all()

    def pending(self, task_id: int) -> list[dict[str, Any]]:
        """The points of ``task_id`` not posted yet, oldest first (a copy)."""
        with self._cond:
            return list(self._queues.get(task_id, ()))

    def flush(self, task_id: int, wait_s: float) -> bool:
        """Wait up to ``wait_s`` for every queued point of ``task_id`` to be posted (or
        dropped); whether none is left."""
        deadline = time.monotonic() + wait_s
        with self._cond:
            while self._queues.get(task_id) or self._sending == task_id:
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)
            return True

    def drop(self, task_id: int) -> None:
        """Forget the points of a finished job."""
        with self._cond:
            self._queues.pop(task_id, None)
            self._cond.notify_all()

    # -- the sending thread ----------------------------------------------------------------
    def _next(self) -> tuple[int, dict[str, Any]]:
        """The oldest point of a task with points (waits for one); marks it in flight."""
        with self._cond:
            while True:
                for task_id, queue in self._queues.items():
                    if queue:
                        self._sending = task_id
                        return task_id, queue[0]
                self._cond.wait()

    def _done(self, task_id: int, point: dict[str, Any], leaves: bool) -> None:
        """``point`` is no longer in flight; it ``leaves`` its queue (posted, or dropped for
        good) unless the queue dropped it meanwhile."""
        with self._cond:
            queue = self._queues.get(task_id)
            if leaves and queue and queue[0] is point:
                queue.popleft()
            elif not leaves and queue is not None:  # its turn passes: another job's points
                self._queues[task_id] = self._queues.pop(task_id)  # are not held behind it
            self._sending = None
            self._cond.notify_all()

    def _run(self) -> None:
        pause = FIRST_PAUSE_S
        while True:
            task_id, point = self._next()
            try:
                self.gateway.post(f"/tasks/{task_id}/progress", json=point, auth=True)
            except GatewayError as exc:
                rule = exc.detail.get("rule") if isinstance(exc.detail, dict) else None
                if rule == "not_assigned_worker" or exc.status >= 500:
                    self._done(task_id, point, leaves=False)  # not yet: the same point again
                    pause = self._pause(pause)
                    continue
                self._warn(task_id, exc)  # 409 duplicate step, 422: dropped
            except Exception as exc:  # noqa: BLE001 - best effort: a connection down, a timeout
                self._warn(task_id, exc)
                self._done(task_id, point, leaves=False)
                pause = self._pause(pause)
                continue
            self._done(task_id, point, leaves=True)
            pause = FIRST_PAUSE_S

    @staticmethod
    def _pause(pause: float) -> float:
        time.sleep(pause)
        return min(2 * pause, MAX_PAUSE_S)

    def _warn(self, task_id: int, exc: Exception) -> None:
        self.errors += 1
        if self.errors <= WARNINGS_LOGGED:
            log.warning("progress point of task %s not posted: %s", task_id, exc)
