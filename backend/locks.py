"""Exclusive ownership of a directory by one live process: a ``flock`` held for its lifetime.

Two gateways on one embedded chain file, or two worker daemons on one job directory, would
each write state the other does not see. The kernel drops the lock when its holder dies, even
by kill -9, so a stale lock file never blocks a restart.
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path
from typing import IO


class AlreadyHeld(RuntimeError):
    """Another live process holds the lock; the message names it and its pid."""


def hold_lock(path: str | Path, what: str) -> IO[str]:
    """Lock ``path`` (created if missing) or raise :class:`AlreadyHeld` naming ``what``; keep
    the returned file open for as long as the ownership must last."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    f = p.open("a+")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        f.seek(0)
        holder = f.read().strip() or "unknown"
        f.close()
        raise AlreadyHeld(
            f"another {what} (pid {holder}) already uses {p.parent}; stop it first"
        ) from None
    f.seek(0)
    f.truncate()
    f.write(str(os.getpid()))
    f.flush()
    return f
