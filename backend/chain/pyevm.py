"""The interpreter's recursion limit, put back after the Ethereum libraries raise it.

Importing ``eth_account``/``web3`` (through ``py_ecc``) sets ``sys.setrecursionlimit(100000)``
and py-evm's ``eth`` package at least 12,288. With such a limit Python's recursion guard no
longer fires before the C stack runs out: one request body nested 100,000 deep segfaulted the
gateway, and the embedded chain with it. :func:`restore_recursion_limit` runs right after those
imports (``backend.chain.client``), so deep input raises ``RecursionError`` again.

The cost: py-evm then cannot nest EVM calls as deep as 1024 frames; a transaction that tries
fails with an error instead. The platform's contracts nest at most a few calls.
"""

from __future__ import annotations

import sys

#: CPython's default recursion limit: what the process had before the imports raised it.
NORMAL_RECURSION_LIMIT = 1000


def restore_recursion_limit() -> None:
    """Lower the recursion limit back to :data:`NORMAL_RECURSION_LIMIT` (never raise it)."""
    if sys.getrecursionlimit() > NORMAL_RECURSION_LIMIT:
        sys.setrecursionlimit(NORMAL_RECURSION_LIMIT)
