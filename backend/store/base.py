"""The content-store interface: put bytes, get them back by CID, verified and size-bounded.

Both backends (:class:`~backend.store.embedded.EmbeddedStore` on disk,
:class:`~backend.store.ipfs_rpc.IpfsRpcStore` over an IPFS node's RPC API) give the same CID for
the same bytes, so a model's CID recorded on chain is valid whichever store wrote it. The rest of
the platform only sees this class and the errors re-exported here.
"""

from __future__ import annotations

import os
import tempfile
from abc import ABC, abstractmethod
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from .cid import CID, cid_key
from .dag import read_file
from .errors import (
    CIDMismatch,
    ContentTooLarge,
    InvalidCID,
    InvalidContent,
    NotFound,
    StoreError,
    StoreUnavailable,
)

__all__ = [
    "CIDMismatch",
    "ContentStore",
    "ContentTooLarge",
    "DEFAULT_MAX_SIZE",
    "InvalidCID",
    "InvalidContent",
    "NotFound",
    "StoreError",
    "StoreUnavailable",
]

DEFAULT_MAX_SIZE = 256 * 2**20
"""Default bound on one piece of content (matches the gateway's ``max_upload_bytes`` default)."""


class ContentStore(ABC):
    """Content-addressed storage of files (model weights, cards, checkpoints).

    Reads go through :func:`~backend.store.dag.read_file`, which checks every block against its
    CID, so a corrupted disk or a lying node raises :class:`CIDMismatch` instead of returning
    wrong bytes. Every read and write is bounded by ``max_size`` (overridable per call).
    """

    def __init__(self, *, max_size: int = DEFAULT_MAX_SIZE) -> None:
        if max_size <= 0:
            raise ValueError(f"max_size must be positive, got {max_size}")
        self.max_size = max_size

    # -- writing -----------------------------------------------------------------------------------
    def add(self, data: bytes, *, pin: bool = True) -> str:
        """Store ``data``; return its CID (CIDv1 base32, as ``ipfs add`` with the store's
        options prints it). Idempotent."""
        self._check_size(len(data), None)
        return self._add_stream(bytes(data), pin=pin)

    def add_file(self, path: str | os.PathLike[str], *, pin: bool = True) -> str:
        """Store a file's bytes, streamed chunk by chunk; return its CID."""
        size = os.path.getsize(path)
        self._check_size(size, None)
        with open(path, "rb") as fh:
            return self._add_stream(fh, pin=pin)

    # -- reading -----------------------------------------------------------------------------------
    def iter_get(self, cid: str | CID, *, max_size: int | None = None) -> Iterator[bytes]:
        """Yield the content of ``cid`` chunk by chunk, each block verified before it is yielded.
        A consumer that needs all-or-nothing must wait for the iterator to finish."""
        root = CID.parse(cid)
        limit = self._limit(max_size)
        return read_file(root, self._read_block, max_size=limit)

    def get(self, cid: str | CID, *, max_size: int | None = None) -> bytes:
        """The whole content of ``cid``, verified; :class:`ContentTooLarge` before reading past
        the bound."""
        return b"".join(self.iter_get(cid, max_size=max_size))

    def get_block(self, cid: str | CID, *, max_bytes: int) -> bytes:
        """One raw block, verified against ``cid`` (what a remote reader rebuilds files from:
        it verifies again, so it trusts no one in between)."""
        parsed = CID.parse(cid)
        block = self._read_block(parsed, max_bytes)
        if len(block) > max_bytes:
            raise ContentTooLarge(len(block), max_bytes, f"block {parsed}")
        parsed.verify(block)
        return block

    def get_to_file(
        self, cid: str | CID, path: str | os.PathLike[str], *, max_size: int | None = None
    ) -> int:
        """Write the content of ``cid`` to ``path`` atomically (temp file + rename, only after
        every block verified); return the number of bytes written."""
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".part")
        size = 0
        try:
            with os.fdopen(fd, "wb") as out:
                for chunk in self.iter_get(cid, max_size=max_size):
                    out.write(chunk)
                    size += len(chunk)
            os.replace(tmp, target)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return size

    # -- pins and health ---------------------------------------------------------------------------
    @abstractmethod
    def has(self, cid: str | CID) -> bool:
        """Whether the root block of ``cid`` is stored (children are checked when read)."""

    @abstractmethod
    def pin(self, cid: str | CID) -> None:
        """Keep ``cid`` (recursively) from garbage collection; :class:`NotFound` if absent."""

    @abstractmethod
    def unpin(self, cid: str | CID) -> None:
        """Remove the pin of ``cid``; :class:`NotFound` if it was not pinned."""

    @abstractmethod
    def pins(self) -> list[str]:
        """CIDv1 strings of all recursively pinned content, sorted."""

    @abstractmethod
    def ping(self) -> dict[str, str]:
        """Cheap health check (backend kind and version); :class:`StoreUnavailable` if down."""

    def with_find_timeout(self, seconds: float) -> ContentStore:
        """This store with reads that give up looking for an absent CID after ``seconds``
        (what a caller that must not wait long uses: the indexer reading task specs). A store
        whose reads never search a network answers at once and returns itself."""
        return self

    def close(self) -> None:  # noqa: B027 - optional hook, most backends hold nothing
        """Release connections/resources (no-op by default)."""

    def __enter__(self) -> ContentStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- backend hooks -----------------------------------------------------------------------------
    @abstractmethod
    def _add_stream(self, source: bytes | BinaryIO, *, pin: bool) -> str:
        """Store bytes or the bytes of a binary file object (checked against the size bound
        before the call, and again while streaming in case the file grows)."""

    @abstractmethod
    def _read_block(self, cid: CID, max_bytes: int) -> bytes:
        """Raw bytes of one block, unverified (the caller verifies); :class:`NotFound` if
        absent, :class:`ContentTooLarge` once more than ``max_bytes`` arrive."""

    # -- helpers -----------------------------------------------------------------------------------
    def _limit(self, max_size: int | None) -> int:
        if max_size is None:
            return self.max_size
        if max_size <= 0:
            raise ValueError(f"max_size must be positive, got {max_size}")
        return min(max_size, self.max_size)

    def _check_size(self, size: int, max_size: int | None) -> None:
        limit = self._limit(max_size)
        if size > limit:
            raise ContentTooLarge(size, limit)

    @staticmethod
    def key(cid: str | CID) -> str:
        """Canonical CIDv1 text of ``cid``."""
        return cid_key(cid)
