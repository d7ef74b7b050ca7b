"""``celery -A workers.daemon.app worker -Q worker.<address>``: the platform's Celery app with
the daemon's job registered. Built from the environment on first access, like
``backend.celery_app``."""

from __future__ import annotations

from typing import Any

from celery import Celery

import workers.daemon.tasks  # noqa: F401 - registers drlaas.handle_offer
from backend.celery_app import make_celery
from backend.settings import load_settings

_app: Celery | None = None


def __getattr__(name: str) -> Any:
    global _app
    if name in {"app", "celery"}:
        if _app is None:
            _app = make_celery(load_settings())
        return _app
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
