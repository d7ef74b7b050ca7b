"""The daemon's log format (``DRLAAS_LOG_FORMAT``): Celery installs its own handlers when the
worker starts, so in ``json`` mode their formatter is replaced once they exist. Lines written
while a job runs carry its ``task_id`` (``workers.daemon.tasks`` sets the context)."""

from __future__ import annotations

import logging
from typing import Any

from celery.signals import after_setup_logger, after_setup_task_logger

from backend.observability.logs import LogFormat, configure_logging, use_format_on


def configure_daemon_logging(fmt: LogFormat) -> None:
    """Use ``fmt`` now (start-up lines) and on the handlers Celery sets up later."""
    if fmt == "text":
        return  # Celery's own readable lines

    configure_logging(fmt)

    def reformat(logger: logging.Logger, *args: Any, **kwargs: Any) -> None:
        use_format_on(logger, fmt)

    after_setup_logger.connect(reformat, weak=False)
    after_setup_task_logger.connect(reformat, weak=False)
