"""Structured logs: one JSON object per line (``DRLAAS_LOG_FORMAT=json``) with ``time``,
``level``, ``logger``, ``message`` and, when the line is about a task, ``task_id``.

The task id comes from ``extra={"task_id": ...}`` on the call or from :data:`task_id_var`,
which the worker's job and the gateway's ``/api/tasks/{id}`` requests set for everything logged
while they run (:func:`task_context`). ``text`` (the default) keeps the usual readable lines.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any, Literal

LogFormat = Literal["text", "json"]
TEXT_FORMAT = "%(asctime)s %(levelname)s %(name)s %(message)s"

#: The task the current code works for (a worker job, a gateway request about one task).
task_id_var: ContextVar[int | None] = ContextVar("drlaas_task_id", default=None)


@contextmanager
def task_context(task_id: int | None) -> Iterator[None]:
    """Tag every log line written inside the block with ``task_id``."""
    token = task_id_var.set(task_id)
    try:
        yield
    finally:
        task_id_var.reset(token)


class JsonFormatter(logging.Formatter):
    """``{"time", "level", "logger", "message", "task_id"?, "exception"?}`` on one line."""

    def format(self, record: logging.LogRecord) -> str:
        doc: dict[str, Any] = {
            "time": dt.datetime.fromtimestamp(record.created, dt.UTC).isoformat(
                timespec="milliseconds"
            ),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        task_id = getattr(record, "task_id", None)
        if task_id is None:
            task_id = task_id_var.get()
        if task_id is not None:
            doc["task_id"] = task_id
        if record.exc_info:
            doc["exception"] = self.formatException(record.exc_info)
        return json.dumps(doc, default=str, ensure_ascii=False)


class _Ours(logging.StreamHandler):  # type: ignore[type-arg]
    """Marks the handler :func:`configure_logging` installed, so calling it again replaces it."""


def make_formatter(fmt: LogFormat) -> logging.Formatter:
    if fmt == "json":
        return JsonFormatter()
    if fmt == "text":
        return logging.Formatter(TEXT_FORMAT)
    raise ValueError(f"DRLAAS_LOG_FORMAT must be 'json' or 'text', got {fmt!r}")


def configure_logging(fmt: LogFormat = "text", level: int = logging.INFO) -> None:
    """One stderr handler on the root logger with the chosen format (replacing the one a
    previous call installed; other handlers, e.g. pytest's, are left alone)."""
    formatter = make_formatter(fmt)
    root = logging.getLogger()
    for h in [h for h in root.handlers if isinstance(h, _Ours)]:
        root.removeHandler(h)
    handler = _Ours(sys.stderr)
    handler.setFormatter(formatter)
    root.addHandler(handler)
    root.setLevel(level)


def use_format_on(logger: logging.Logger, fmt: LogFormat) -> None:
    """Put the chosen format on every handler of ``logger`` (Celery installs its own)."""
    formatter = make_formatter(fmt)
    for h in logger.handlers:
        h.setFormatter(formatter)
