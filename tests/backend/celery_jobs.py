"""A Celery app for worker-process tests: the platform app plus a job that records when it
starts and finishes, so a test can kill the worker mid-job and count executions."""

from __future__ import annotations

import os
import time
from pathlib import Path

from backend.celery_app import make_celery
from backend.settings import load_settings

app = make_celery(load_settings())


@app.task(name="tests.record")
def record(path: str, token: str, seconds: float) -> int:
    with Path(path).open("a") as f:
        f.write(f"start {token} {os.getpid()}\n")
    time.sleep(seconds)
    with Path(path).open("a") as f:
        f.write(f"done {token} {os.getpid()}\n")
    return os.getpid()
