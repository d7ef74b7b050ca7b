"""One daemon per worker data directory: an exclusive ``flock`` held for the process lifetime.

Two daemons on one directory would consume the same offer queue and write the same job
directories (issue 7: orphaned daemons ran twice after a restart of ``drlaas up``). The kernel
drops the lock when the holder dies, even by kill -9, so a stale lock file never blocks.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path
from typing import IO

LOCK_FILE = "daemon.lock"


class DaemonAlreadyRunning(RuntimeError):
    """Another live process holds the directory; the message names its pid."""


def hold_daemon_lock(data_dir: str | Path) -> IO[str]:
    """Lock ``<data_dir>/daemon.lock`` or raise :class:`DaemonAlreadyRunning`; keep the
    returned file open for as long as the daemon runs."""
    path = Path(data_dir) / LOCK_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    f = path.open("a+")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        f.seek(0)
        holder = f.read().strip() or "unknown"
        f.close()
        raise DaemonAlreadyRunning(
            f"another worker daemon (pid {holder}) already runs on {path.parent}; stop it first"
        ) from None
    f.seek(0)
    f.truncate()
    f.write(str(os.getpid()))
    f.flush()
    return f
