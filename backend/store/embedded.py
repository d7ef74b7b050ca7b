"""Embedded content store: IPFS-compatible blocks in a directory, no daemon.

Layout under ``root``::

    blocks/<xy>/<cidv1>   one file per block (raw leaf or dag-pb node); <xy> = the two characters
                          before the CID's last one, like go-ipfs' flatfs "next-to-last/2" shard
    pins/<cidv1>          empty marker file per recursively pinned root

Every file is written to a temp file in the target directory and renamed into place, so readers
in other processes (gateway, workers) never see a half-written block, and two writers of the
same block simply race to put identical bytes. Blocks are verified when read, so a block
corrupted on disk raises :class:`CIDMismatch` naming it.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import BinaryIO

from .base import DEFAULT_MAX_SIZE, ContentStore
from .cid import CID, cid_key
from .dag import build_dag, iter_chunks
from .errors import CIDMismatch, ContentTooLarge, NotFound, StoreUnavailable


class EmbeddedStore(ContentStore):
    """Block store on the local file system yielding the same CIDs as an IPFS node."""

    def __init__(
        self, root: str | os.PathLike[str], *, max_size: int = DEFAULT_MAX_SIZE, fsync: bool = True
    ) -> None:
        super().__init__(max_size=max_size)
        self.root = Path(root).expanduser().resolve()
        self.fsync = fsync
        self._blocks = self.root / "blocks"
        self._pins = self.root / "pins"
        try:
            self._blocks.mkdir(parents=True, exist_ok=True)
            self._pins.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise StoreUnavailable(str(self.root), f"cannot create store directory: {e}", 0) from e

    def __repr__(self) -> str:
        return f"EmbeddedStore({str(self.root)!r})"

    # -- paths -------------------------------------------------------------------------------------
    def block_path(self, cid: str | CID) -> Path:
        """File holding the block ``cid`` (exposed so tests and repair tools can reach it)."""
        key = cid_key(cid)
        return self._blocks / key[-3:-1] / key

    # -- writing -----------------------------------------------------------------------------------
    def _atomic_write(self, path: Path, data: bytes) -> None:
        new_dir = not path.parent.is_dir()
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-")
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
                if self.fsync:
                    fh.flush()
                    os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        if self.fsync:  # the rename, and a new shard's entry, outlive a power cut too: the
            # file's own fsync does not cover them, and a CID recorded on chain named a block
            # that was gone after a crash
            _fsync_dir(path.parent)
            if new_dir:
                _fsync_dir(path.parent.parent)

    def _put_block(self, cid: CID, block: bytes) -> None:
        path = self.block_path(cid)
        try:  # no more than the block: a damaged file of any size was read whole
            with open(path, "rb") as fh:
                existing = fh.read(len(block) + 1)
        except OSError:  # absent, or unreadable (a directory in its place): written below
            existing = None
        if existing is not None:
            try:
                cid.verify(existing)
                return  # already stored and intact
            except CIDMismatch:
                pass  # corrupted copy on disk: overwrite it with the good bytes
        try:
            self._atomic_write(path, block)
        except OSError as e:
            raise StoreUnavailable(str(self.root), f"cannot write block {cid}: {e}", 5.0) from e

    def _add_stream(self, source: bytes | BinaryIO, *, pin: bool) -> str:
        root, _ = build_dag(iter_chunks(source), self._put_block, max_size=self.max_size)
        key = str(root)
        if pin:
            self._atomic_write(self._pins / key, b"")
        return key

    # -- reading -----------------------------------------------------------------------------------
    def _read_block(self, cid: CID, max_bytes: int) -> bytes:
        path = self.block_path(cid)
        try:
            with open(path, "rb") as fh:
                size = os.fstat(fh.fileno()).st_size
                if size > max_bytes:
                    raise ContentTooLarge(size, max_bytes, f"block {cid}")
                return fh.read(max_bytes + 1)
        except FileNotFoundError:
            raise NotFound(str(cid), f"no block file {path}") from None
        except OSError as e:
            raise StoreUnavailable(str(self.root), f"cannot read block {cid}: {e}", 5.0) from e

    def has(self, cid: str | CID) -> bool:
        return self.block_path(cid).is_file()

    # -- pins --------------------------------------------------------------------------------------
    def pin(self, cid: str | CID) -> None:
        """Pin after checking that the whole DAG is present and intact (reads every block)."""
        key = cid_key(cid)
        for _ in self.iter_get(key):
            pass
        self._atomic_write(self._pins / key, b"")

    def unpin(self, cid: str | CID) -> None:
        key = cid_key(cid)
        try:
            (self._pins / key).unlink()
        except FileNotFoundError:
            raise NotFound(key, "not pinned") from None

    def pins(self) -> list[str]:
        return sorted(p.name for p in self._pins.iterdir() if not p.name.startswith("."))

    def blocks(self) -> list[str]:
        """CIDs of all stored blocks (for inspection and tests)."""
        return sorted(
            p.name
            for d in self._blocks.iterdir()
            if d.is_dir()
            for p in d.iterdir()
            if not p.name.startswith(".")
        )

    def ping(self) -> dict[str, str]:
        if not os.access(self._blocks, os.W_OK):
            raise StoreUnavailable(str(self.root), "store directory is not writable", 0)
        return {"backend": "embedded", "root": str(self.root)}


def _fsync_dir(path: Path) -> None:
    """Flush a directory's entries (a rename or a new file in it) to disk."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
