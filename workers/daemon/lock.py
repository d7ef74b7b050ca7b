"""One daemon per worker data directory (issue 7: orphaned daemons ran twice after a restart of
``drlaas up``): two daemons on one directory would consume the same offer queue and write the
same job directories."""

from __future__ import annotations

from pathlib import Path
from typing import IO

from backend.locks import hold_lock

LOCK_FILE = "daemon.lock"


def hold_daemon_lock(data_dir: str | Path) -> IO[str]:
    """Lock ``<data_dir>/daemon.lock`` or raise :class:`backend.locks.AlreadyHeld`; keep the
    returned file open for as long as the daemon runs."""
    return hold_lock(Path(data_dir) / LOCK_FILE, "worker daemon")
