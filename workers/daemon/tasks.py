"""The Celery job of the worker daemon, ``drlaas.handle_offer(task_id, worker)``, and the
``on_offer`` callable the indexer uses to enqueue it.

Jobs go to the worker's own queue ``worker.<address>`` with the idempotent id
``offer:<task_id>:<worker>``; ``acks_late`` + ``reject_on_worker_lost`` mean a worker killed
mid-training gets the job again when it comes back, and :class:`OfferHandler` resumes from the
job's checkpoint. Only :class:`~workers.daemon.handler.Transient` errors (store or node down)
are retried, with capped exponential backoff and jitter (STYLE.md, "Workers"); when the last
retry fails too, the handler gives the job back (``OfferHandler.give_up``: abandonOffer) rather
than leave its offer accepted with nobody working on it, and declines an offer it was still
checking (declineOffer) rather than leave it to expire. A job whose model is trained (only an
upload or a transaction is missing) is not given back while its deadline can still be met:
it is retried past MAX_RETRIES, at most every RETRY_CAP_S and within half the time left
(``OfferHandler.delivery_time_left``).

The handler of a daemon process is built once from the environment (``runtime_from_env``):
``DRLAAS_WORKER_KEY`` (key file), ``DRLAAS_GATEWAY`` (gateway URL), ``DRLAAS_WORKER_DATA``
(default ``<data>/workers/<address>``), ``DRLAAS_WORKER_MAX_JOBS`` (default 1),
``DRLAAS_WORKER_CHECKPOINT_EVERY`` (updates between checkpoints, default 2),
``DRLAAS_WORKER_CHECKPOINT_INTERVAL_S`` (least seconds between checkpoints, default 30),
``DRLAAS_WORKER_MODEL_CACHE_BYTES`` (bound on the verified expert models kept for later offers,
default 2 GiB, 0 for none), ``DRLAAS_WORKER_OFFER_FETCH_BYTES`` (model bytes one offer's check
may download, default 256 MiB). All are checked first (``worker_env``, which ``drlaas worker
run`` also calls before it makes a key or registers): a bad value is a ``WorkerEnvError``
naming the variable and its value, before the chain or the store is opened.

A warm or cold shutdown of the daemon (SIGTERM, SIGINT, SIGQUIT: Celery's
``worker_shutting_down``) marks the training start in progress as stopped
(``OfferHandler.note_stop``), so a ``systemctl restart`` is not counted as the job dying.
"""

from __future__ import annotations

import logging
import math
import os
import random
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from celery import Celery, shared_task
from celery.signals import worker_shutting_down

from backend.celery_app import make_celery, worker_queue
from backend.chain.addresses import checksum
from backend.observability.logs import task_context
from backend.settings import Settings, load_settings
from workers.daemon import job as jobs
from workers.daemon.experts import DEFAULT_CACHE_BYTES, DEFAULT_OFFER_FETCH_BYTES
from workers.daemon.handler import OfferHandler, Transient
from workers.daemon.links import SetupError

log = logging.getLogger(__name__)

TASK_NAME = "drlaas.handle_offer"
MAX_RETRIES = 8
RETRY_BASE_S = 2.0
RETRY_CAP_S = 120.0


def offer_key(task_id: int, worker: str) -> str:
    """The idempotent job id of one offer."""
    return f"offer:{int(task_id)}:{checksum(worker)}"


def retry_delay(retries: int, *, rng: random.Random | None = None) -> float:
    """Full-jitter exponential backoff: uniform in [0, min(cap, base * 2**retries)], at least
    half a second so a down service is not hammered."""
    ceiling = min(RETRY_CAP_S, RETRY_BASE_S * 2**retries)
    return max(0.5, (rng or random).uniform(0, ceiling))


def make_on_offer(settings: Settings, app: Celery | None = None) -> Callable[[int, str], None]:
    """The ``on_offer(task_id, worker)`` callable for the indexer: enqueue the job on the
    worker's queue under its idempotent key."""
    app = app or make_celery(settings)

    def warm() -> None:
        """Open the producer's broker connection now (the first send otherwise pays for it,
        and for creating the embedded broker's tables, inside the first task submission)."""
        with app.pool.acquire(block=True) as conn:
            conn.ensure_connection(max_retries=3)
            conn.default_channel  # noqa: B018 - creating the channel is the point

    def on_offer(task_id: int, worker: str) -> None:
        worker = checksum(worker)
        app.send_task(
            TASK_NAME,
            args=[int(task_id), worker],
            queue=worker_queue(worker),
            task_id=offer_key(task_id, worker),
        )

    on_offer.warm = warm  # type: ignore[attr-defined]
    return on_offer


_runtime: OfferHandler | None = None
_lock = threading.Lock()


class WorkerEnvError(SetupError, ValueError):
    """A ``DRLAAS_WORKER_*`` (or ``DRLAAS_GATEWAY``) variable the daemon cannot run with; the
    message names the variable and its value (the CLI prints it as one line)."""


@dataclass(frozen=True)
class WorkerEnv:
    """The daemon's settings from the environment, every one checked (see module docstring)."""

    key_file: Path
    gateway_url: str | None
    data_dir: Path | None
    """None: ``<data>/workers/<address>``, known once the key is read."""
    max_jobs: int = 1
    checkpoint_every: int = jobs.CHECKPOINT_EVERY
    checkpoint_interval_s: float = jobs.CHECKPOINT_INTERVAL_S
    cache_bytes: int = DEFAULT_CACHE_BYTES
    max_offer_fetch_bytes: int = DEFAULT_OFFER_FETCH_BYTES


def worker_env(environ: Mapping[str, str] | None = None) -> WorkerEnv:
    """Read and check the daemon's variables before anything is opened, asked or registered:
    ``int()`` of a bad DRLAAS_WORKER_MAX_JOBS failed after the chain and pins were set up
    (with no variable named), in a daemon started by Celery at its first job, and a NaN or
    negative interval, or 0 jobs, was taken as given. :class:`WorkerEnvError` otherwise."""
    env = os.environ if environ is None else environ
    key_file = env.get("DRLAAS_WORKER_KEY", "").strip()
    if not key_file:
        raise WorkerEnvError("DRLAAS_WORKER_KEY is not set: the daemon needs its key file")
    gateway_url = env.get("DRLAAS_GATEWAY", "").strip() or None
    if gateway_url is not None:
        parts = urlsplit(gateway_url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise WorkerEnvError(
                f"DRLAAS_GATEWAY must be an http(s) URL such as http://127.0.0.1:8000, got "
                f"{gateway_url!r}")
    data_text = env.get("DRLAAS_WORKER_DATA", "").strip()
    data_dir = Path(data_text).expanduser() if data_text else None
    if data_dir is not None and data_dir.exists() and not data_dir.is_dir():
        raise WorkerEnvError(
            f"DRLAAS_WORKER_DATA must be a directory, got {data_text!r} (not a directory)")
    return WorkerEnv(
        key_file=Path(key_file).expanduser(),
        gateway_url=gateway_url,
        data_dir=data_dir,
        max_jobs=_env_int(env, "DRLAAS_WORKER_MAX_JOBS", 1, least=1, unit="jobs"),
        checkpoint_every=_env_int(env, "DRLAAS_WORKER_CHECKPOINT_EVERY",
                                  jobs.CHECKPOINT_EVERY, least=1, unit="updates"),
        checkpoint_interval_s=env_seconds(env, "DRLAAS_WORKER_CHECKPOINT_INTERVAL_S",
                                           jobs.CHECKPOINT_INTERVAL_S),
        cache_bytes=_env_int(env, "DRLAAS_WORKER_MODEL_CACHE_BYTES", DEFAULT_CACHE_BYTES,
                             least=0, unit="bytes"),
        max_offer_fetch_bytes=_env_int(env, "DRLAAS_WORKER_OFFER_FETCH_BYTES",
                                       DEFAULT_OFFER_FETCH_BYTES, least=0, unit="bytes"),
    )


def runtime_from_env(settings: Settings | None = None) -> OfferHandler:
    """Build this process's handler from the environment (see module docstring); the
    variables are checked first (:func:`worker_env`)."""
    from workers.daemon.gateway import Gateway
    from workers.daemon.keys import load_key
    from workers.daemon.links import (
        PIN_FILE,
        chain_url,
        connect_worker,
        open_store,
        pinned_platform,
        record_pin,
    )

    config = worker_env()
    settings = settings or load_settings()
    try:
        account = load_key(config.key_file)
    except (OSError, ValueError) as exc:
        raise WorkerEnvError(f"DRLAAS_WORKER_KEY={str(config.key_file)!r}: {exc}") from None
    gateway_url = config.gateway_url
    data = config.data_dir or settings.data_dir / "workers" / account.address
    pin = pinned_platform(settings, gateway_url, data / PIN_FILE)
    platform = connect_worker(
        chain_url(settings, gateway_url), account, pin.deployment, pin.chain_id
    )
    if pin.pin_file is not None and gateway_url:  # first use: the chain id the node reported
        record_pin(pin.pin_file, gateway_url, pin.deployment, platform.chain.chain_id)
    return OfferHandler(
        account=account,
        platform=platform,
        store=open_store(settings),
        data_dir=data,
        gateway=(Gateway(gateway_url, account, chain_id=platform.chain.chain_id)
                 if gateway_url else None),
        max_jobs=config.max_jobs,
        checkpoint_every=config.checkpoint_every,
        checkpoint_interval_s=config.checkpoint_interval_s,
        cache_bytes=config.cache_bytes,
        max_offer_fetch_bytes=config.max_offer_fetch_bytes,
    )


def _env_int(env: Mapping[str, str], name: str, default: int, *, least: int, unit: str) -> int:
    """A whole number >= ``least`` from the environment (``default`` when unset or blank);
    WorkerEnvError naming the variable and its value otherwise."""
    text = env.get(name, "").strip()
    if not text:
        return default
    # no "1_0", "+1", "½"; and no 5,000-digit text, which int() refuses with its own error
    value = int(text) if text.isascii() and text.isdigit() and len(text) <= 30 else None
    if value is None or value < least:
        raise WorkerEnvError(f"{name} must be a whole number of {unit} >= {least}, got {text!r}")
    return value


def env_seconds(env: Mapping[str, str], name: str, default: float, *, note: str = "") -> float:
    """A finite number of seconds >= 0 from the environment (``default`` when unset or blank);
    WorkerEnvError naming the variable and its value otherwise (float() takes 'nan' and
    'inf'); ``note`` says more in the message (what 0 means)."""
    text = env.get(name, "").strip()
    if not text:
        return default
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not math.isfinite(value) or value < 0:
        raise WorkerEnvError(f"{name} must be a number of seconds >= 0{note}, got {text!r}")
    return value


def runtime() -> OfferHandler:
    global _runtime
    with _lock:
        if _runtime is None:
            _runtime = runtime_from_env()
        return _runtime


@worker_shutting_down.connect
def _note_stop(sig: str = "", how: str = "", **_: Any) -> None:
    """Celery's SIGTERM / SIGINT / SIGQUIT handler, in the daemon's main process: a deliberate
    stop is not a death of the training job (``OfferHandler.note_stop``). Reads the handler
    without the lock: a signal handler must not wait for a lock its own thread may hold."""
    handler = _runtime
    if handler is not None:
        handler.note_stop(f"{sig or 'signal'}, {how.lower() or 'warm'} shutdown")


def set_runtime(handler: OfferHandler | None) -> None:
    """Install a handler (the daemon command builds it once at start-up; tests inject one)."""
    global _runtime
    with _lock:
        _runtime = handler


@shared_task(
    name=TASK_NAME,
    bind=True,
    acks_late=True,
    reject_on_worker_lost=True,
    max_retries=MAX_RETRIES,
)
def handle_offer(self: Any, task_id: int, worker: str) -> dict[str, Any]:
    """Accept or decline the offer of ``task_id`` to ``worker``, train, upload, submit."""
    try:
        with task_context(int(task_id)):  # JSON log lines of this job carry its task id
            return runtime().handle(int(task_id), worker)
    except Transient as exc:
        retries = self.request.retries
        if retries >= self.max_retries:  # the last try: give the job back, unless it is trained
            left = runtime().delivery_time_left(int(task_id))
            if left is not None and left > 0:
                countdown = min(retry_delay(retries), left / 2)
                log.warning("task %s: %s; the trained model is kept, retry %d in %.0f s "
                            "(%.0f s before the deadline's margin)", task_id, exc, retries + 1,
                            countdown, left)
                raise self.retry(exc=exc, countdown=countdown, max_retries=retries + 1) from exc
            reason = f"gave up after {retries} retries: {exc}"
            log.error("task %s: %s", task_id, reason)
            return runtime().give_up(int(task_id), reason)  # Transient if the node is down too
        raise self.retry(exc=exc, countdown=retry_delay(self.request.retries)) from exc
