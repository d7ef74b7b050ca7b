"""Celery for the worker daemon: ``make_celery(settings)`` and per-worker queues.

Brokers (DRLAAS_BROKER, see backend.settings):

* ``embedded``: kombu's SQLAlchemy transport over ``<data>/broker.sqlite`` (no server), results
  in ``db+sqlite:///<data>/results.sqlite``. kombu polls a virtual transport every
  ``Transport.polling_interval`` seconds (1 s by default, ~1 s per round trip). The transport
  option ``polling_interval`` cannot be used for this transport, because kombu forwards every
  SQLAlchemy transport option to ``sqlalchemy.create_engine``, which rejects it. The supported
  hook is kombu's own: a transport *class* chosen with Celery's ``broker_transport`` setting
  (kombu resolves ``"module:Class"`` paths given explicitly, not taken from the URL). So
  :class:`EmbeddedSQLATransport` subclasses the SQLAlchemy transport with
  ``polling_interval = 0.05`` and the broker URL is the bare ``sqlite:///...`` it connects to.
  Nothing is patched globally. Its channel also makes ``acks_late`` hold across ``kill -9``
  on per-worker queues (see :class:`_DurableChannel`).
* ``redis://`` / ``amqp://``: passed through.

Task defaults follow Celery's guidance for long jobs (STYLE.md, "Workers"): ``acks_late`` with
``task_reject_on_worker_lost`` (a job whose worker dies is redelivered, not lost), prefetch 1,
JSON only (never pickle). Jobs go to per-worker queues ``worker.<address>``.

``celery -A backend.celery_app worker -Q worker.0x... --pool solo`` reads the settings from the
environment when the ``app`` attribute is first accessed.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path
from queue import Empty
from typing import Any

from celery import Celery, shared_task
from kombu.transport import sqlalchemy as kombu_sqla
from kombu.utils.encoding import bytes_to_str
from sqlalchemy import text
from sqlalchemy.exc import IntegrityError

from backend.settings import Settings, load_settings

#: Seconds between polls of the embedded SQLite broker (TOOLCHAIN.md: ~67 ms round trip).
EMBEDDED_POLLING_INTERVAL_S = 0.05
#: Redis redelivers an unacknowledged message after this long; acks_late jobs may run for hours,
#: so it must exceed the longest job (Celery docs, "Visibility timeout").
REDIS_VISIBILITY_TIMEOUT_S = 12 * 3600
DEFAULT_QUEUE = "drlaas"
WORKER_QUEUE_PREFIX = "worker."


class _DurableChannel(kombu_sqla.Channel):
    """kombu's SQLAlchemy channel made to honour ``acks_late`` across a ``kill -9``.

    Upstream (kombu 5.7) marks a row invisible when it is fetched and never touches it again:
    acknowledged and in-flight messages look the same, so a consumer killed mid-job loses its
    message for good (measured: task stuck in STARTED, row ``visible=0``). Here an acked or
    rejected message's row is deleted, a restored one (warm shutdown, ``requeue``) is made
    visible again in place, and when a consumer starts on a per-worker queue
    (``worker.<address>``, one consumer by design) every row still invisible there belongs to a
    dead predecessor and is made visible: the job is redelivered when the worker comes back.
    Uses the upstream channel's ``session``/``message_cls``/``_get_or_create``.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._rows: dict[str, int] = {}  # delivery tag -> kombu_message.id of fetched rows
        self._hostname = self.connection.client.hostname

    def _open(self) -> Any:
        """The engine and session factory, also once kombu has detached this channel from its
        connection (``close_channel`` sets ``connection = None``, and a late ack or the QoS
        restore at shutdown or garbage collection may still need the session): measured as an
        intermittent ``'NoneType' object has no attribute 'client'``."""
        if self.connection is None:
            return self._engines[self._hostname]
        return super()._open()

    def _get_or_create(self, queue: str) -> Any:
        """The queue's row, also when another process inserts it between upstream's look-up
        and its insert: upstream's lock is per process, so a gateway publishing to a new queue
        while a worker starts on it lost the race with ``UNIQUE constraint failed:
        kombu_queue.name``, which killed the worker (measured in CI)."""
        try:
            return super()._get_or_create(queue)
        except IntegrityError:
            self.session.rollback()
            return self.session.query(self.queue_cls).filter(self.queue_cls.name == queue).one()

    def _get(self, queue: str, timeout: Any = None) -> dict[str, Any]:
        q = self._get_or_create(queue)
        M = self.message_cls
        if self.session.bind.name == "sqlite":  # take the write lock before reading
            self.session.execute(text("BEGIN IMMEDIATE TRANSACTION"))
        try:
            row = (
                self.session.query(M)
                .filter(M.queue_id == q.id, M.visible.is_(True))
                .order_by(M.sent_at, M.id)
                .limit(1)
                .with_for_update()
                .first()
            )
            if row is None:
                raise Empty()
            row.visible = False
            payload: dict[str, Any] = json.loads(bytes_to_str(row.payload))
            self._rows[payload["properties"]["delivery_tag"]] = row.id
            return payload
        finally:
            self.session.commit()

    def _settle(self, delivery_tag: str, *, redeliver: bool) -> bool:
        row_id = self._rows.pop(delivery_tag, None)
        if row_id is None:
            return False
        rows = self.session.query(self.message_cls).filter(self.message_cls.id == row_id)
        if redeliver:
            rows.update({"visible": True}, synchronize_session=False)
        else:
            rows.delete(synchronize_session=False)
        self.session.commit()
        return True

    def basic_ack(self, delivery_tag: str, multiple: bool = False) -> None:
        super().basic_ack(delivery_tag, multiple=multiple)
        self._settle(delivery_tag, redeliver=False)

    def basic_reject(self, delivery_tag: str, requeue: bool = False) -> None:
        super().basic_reject(delivery_tag, requeue=requeue)  # requeue goes through _restore
        self._settle(delivery_tag, redeliver=False)

    def _restore(self, message: Any) -> None:
        if not self._settle(message.delivery_tag, redeliver=True):
            super()._restore(message)

    def basic_consume(self, queue: str, *args: Any, **kwargs: Any) -> Any:
        if queue.startswith(WORKER_QUEUE_PREFIX):
            q = self._get_or_create(queue)
            M = self.message_cls
            self.session.query(M).filter(M.queue_id == q.id, M.visible.is_(False)).update(
                {"visible": True}, synchronize_session=False
            )
            self.session.commit()
        return super().basic_consume(queue, *args, **kwargs)


class EmbeddedSQLATransport(kombu_sqla.Transport):
    """kombu's SQLAlchemy transport, polling every 50 ms instead of every second, with
    :class:`_DurableChannel` so that unacknowledged jobs survive a killed worker."""

    Channel = _DurableChannel
    polling_interval = EMBEDDED_POLLING_INTERVAL_S


def worker_queue(address: str) -> str:
    """The queue of the worker daemon running for ``address`` (checksummed, so one queue per
    address whatever case a caller used)."""
    from backend.chain.addresses import checksum

    return f"{WORKER_QUEUE_PREFIX}{checksum(address)}"


def _default_result_backend(settings: Settings) -> str:
    kind = settings.broker_service.kind
    if kind == "redis":
        return settings.broker_service.url
    if kind == "embedded" or settings.database_url.startswith("sqlite"):
        # A SQLite file of its own (AMQP has no durable result store; rpc:// results die with
        # the client), so result writes never lock the platform database.
        return f"db+sqlite:///{settings.data_dir / 'results.sqlite'}"
    # PostgreSQL copes with concurrent writers: Celery's tables (celery_*) live beside the
    # platform's, and alembic's autogenerate ignores them (migrations/env.py).
    return f"db+{settings.database_url}"


def broker_config(settings: Settings) -> dict[str, Any]:
    """Celery settings selecting broker, transport and result backend for ``settings``."""
    svc = settings.broker_service
    conf: dict[str, Any] = {
        "result_backend": settings.result_backend or _default_result_backend(settings)
    }
    if svc.embedded:
        conf["broker_url"] = f"sqlite:///{settings.data_dir / 'broker.sqlite'}"
        conf["broker_transport"] = f"{__name__}:EmbeddedSQLATransport"
    else:
        conf["broker_url"] = svc.url
    if svc.kind == "redis":
        conf["broker_transport_options"] = {"visibility_timeout": REDIS_VISIBILITY_TIMEOUT_S}
        conf["result_backend_transport_options"] = {
            "visibility_timeout": REDIS_VISIBILITY_TIMEOUT_S
        }
    for url in (conf["broker_url"], conf["result_backend"]):
        path = url.removeprefix("db+").removeprefix("sqlite:///")
        if path != url.removeprefix("db+"):  # a SQLite file: its directory must exist
            Path(path).parent.mkdir(parents=True, exist_ok=True)
    return conf


def make_celery(settings: Settings, *, name: str = "drlaas") -> Celery:
    """A Celery app for ``settings`` with the platform's task defaults."""
    app = Celery(name, set_as_current=False)
    app.conf.update(
        broker_config(settings),
        task_serializer="json",
        result_serializer="json",
        accept_content=["json"],
        result_accept_content=["json"],
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        task_default_queue=DEFAULT_QUEUE,
        task_create_missing_queues=True,
        task_track_started=True,
        result_extended=True,
        result_expires=7 * 24 * 3600,
        broker_connection_retry_on_startup=True,
        worker_hijack_root_logger=False,
        enable_utc=True,
        timezone="UTC",
    )
    return app


@shared_task(name="drlaas.ping")
def ping(token: str) -> dict[str, Any]:
    """Echo ``token`` with who answered: proves a broker round trip to a worker process."""
    return {"pong": token, "pid": os.getpid(), "host": socket.gethostname()}


_app: Celery | None = None


def __getattr__(name: str) -> Any:
    # ``celery -A backend.celery_app`` looks up ``app``: build it on first access from the
    # environment, so importing this module has no side effects.
    global _app
    if name in {"app", "celery"}:
        if _app is None:
            _app = make_celery(load_settings())
        return _app
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
