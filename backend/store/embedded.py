"""Embedded content store: IPFS-compatible blocks in a directory, no daemon.

Layout under ``root``::

    blocks/<xy>/<cidv1>   one file per block (raw leaf or dag-pb node); <xy> = the two characters
                          before the CID's last one, like go-ipfs' flatfs "next-to-last/2" shard
    pins/<cidv1>          empty marker file per recursively pinned root

Every file is written to a temp file in the target directory and renamed into place, so readers
in other processes (gateway, workers) never see a half-written block, and two writers of the
same block simply race to put identical bytes. Blocks are verified when read, so a block
corrupted on disk raises :class:`CIDMismatch` naming it.

A writer killed between its temp file and the rename leaves a ``.tmp-*`` file behind; opening
the store removes those older than ``stale_temp_s`` (an hour by default: a live writer's temp
file lives for one block's write and fsync), and a writer whose temp file was removed anyway
(stopped for longer than that) writes the block again rather than fail. Only files whose name
is a canonical CIDv1 are blocks or pins (:meth:`EmbeddedStore.pins`).
"""

from __future__ import annotations

import logging
import os
import tempfile
import time
from pathlib import Path
from typing import BinaryIO

from .base import DEFAULT_MAX_SIZE, ContentStore
from .cid import CID, cid_key
from .dag import build_dag, iter_chunks
from .errors import CIDMismatch, ContentTooLarge, InvalidCID, NotFound, StoreUnavailable

log = logging.getLogger(__name__)

TEMP_PREFIX = ".tmp-"
"""Name prefix of the temp files blocks and pins are written to before their rename."""
STALE_TEMP_S = 3600.0
"""Age (seconds since last modified) past which a temp file is taken as left by a writer that
died before its rename, and removed when a store opens. A live writer holds its temp file for
one block's write and fsync; a younger file may belong to another process writing now."""
WRITE_ATTEMPTS = 2
"""Tries of one block or pin write: a second one when the temp file vanished before its rename
(removed as stale while its writer was stopped)."""


class EmbeddedStore(ContentStore):
    """Block store on the local file system yielding the same CIDs as an IPFS node."""

    def __init__(
        self,
        root: str | os.PathLike[str],
        *,
        max_size: int = DEFAULT_MAX_SIZE,
        fsync: bool = True,
        stale_temp_s: float = STALE_TEMP_S,
    ) -> None:
        super().__init__(max_size=max_size)
        if not stale_temp_s >= 0:  # also refuses NaN
            raise ValueError(f"stale_temp_s must be a number of seconds >= 0, got {stale_temp_s}")
        self.root = Path(root).expanduser().resolve()
        self.fsync = fsync
        self._blocks = self.root / "blocks"
        self._pins = self.root / "pins"
        try:
            self._blocks.mkdir(parents=True, exist_ok=True)
            self._pins.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise StoreUnavailable(str(self.root), f"cannot create store directory: {e}", 0) from e
        self._not_cids: set[str] = set()  # names pins() already warned about
        self.removed_temp_files = self.remove_stale_temp_files(stale_temp_s)
        """Leftover temp files removed when this store opened (for logs and tests)."""

    def __repr__(self) -> str:
        return f"EmbeddedStore({str(self.root)!r})"

    # -- leftovers ---------------------------------------------------------------------------------
    def remove_stale_temp_files(self, older_than_s: float = STALE_TEMP_S) -> list[Path]:
        """Remove the ``.tmp-*`` files of ``pins/`` and the block shards last modified more than
        ``older_than_s`` seconds ago: a writer killed before its rename leaves one, and nothing
        else ever removes it. Younger ones are kept (another process may be writing them);
        entries that are not regular files are never touched. Best effort: a file that cannot
        be removed is logged, never an error (a read-only store still opens). Returns the
        files removed."""
        now = time.time()
        removed: list[Path] = []
        try:
            shards = [e.path for e in os.scandir(self._blocks) if e.is_dir(follow_symlinks=False)]
        except OSError as e:
            log.warning("store %s: cannot list its blocks for stale temp files: %s", self.root, e)
            shards = []
        for directory in [str(self._pins), *shards]:
            try:
                entries = list(os.scandir(directory))
            except OSError as e:
                log.warning("store %s: cannot list %s for stale temp files: %s", self.root,
                            directory, e)
                continue
            for entry in entries:
                if not entry.name.startswith(TEMP_PREFIX):
                    continue
                try:
                    if not entry.is_file(follow_symlinks=False):
                        continue
                    if now - entry.stat(follow_symlinks=False).st_mtime <= older_than_s:
                        continue
                    os.unlink(entry.path)
                except FileNotFoundError:
                    continue  # renamed by its writer, or removed by another store opening
                except OSError as e:
                    log.warning("store %s: cannot remove stale temp file %s: %s", self.root,
                                entry.path, e)
                    continue
                removed.append(Path(entry.path))
        if removed:
            log.info("store %s: removed %d temp file(s) left by interrupted writes",
                     self.root, len(removed))
        return removed

    # -- paths -------------------------------------------------------------------------------------
    def block_path(self, cid: str | CID) -> Path:
        """File holding the block ``cid`` (exposed so tests and repair tools can reach it)."""
        key = cid_key(cid)
        return self._blocks / key[-3:-1] / key

    # -- writing -----------------------------------------------------------------------------------
    def _atomic_write(self, path: Path, data: bytes, what: str) -> None:
        """Write ``path`` whole or not at all; a disk full or failing is
        :class:`StoreUnavailable` naming ``what`` (retried by its callers: a raw OSError of a
        pin failed a worker's job and threw its trained model away)."""
        try:
            self._write_and_rename(path, data)
        except OSError as e:
            raise StoreUnavailable(str(self.root), f"cannot write {what}: {e}", 5.0) from e

    def _write_and_rename(self, path: Path, data: bytes) -> None:
        new_dir = not path.parent.is_dir()
        for attempt in range(1, WRITE_ATTEMPTS + 1):
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=TEMP_PREFIX)
            try:
                with os.fdopen(fd, "wb") as fh:
                    fh.write(data)
                    if self.fsync:
                        fh.flush()
                        os.fsync(fh.fileno())
                os.replace(tmp, path)
                break
            except FileNotFoundError:
                vanished = not os.path.lexists(tmp)
                Path(tmp).unlink(missing_ok=True)
                if attempt == WRITE_ATTEMPTS or not vanished:
                    raise
                log.warning("store %s: temp file %s vanished before its rename (removed as "
                            "stale by another process?); writing %s again", self.root, tmp,
                            path.name)
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
        self._atomic_write(path, block, f"block {cid}")

    def _add_stream(self, source: bytes | BinaryIO, *, pin: bool) -> str:
        root, _ = build_dag(iter_chunks(source), self._put_block, max_size=self.max_size)
        key = str(root)
        if pin:
            self._atomic_write(self._pins / key, b"", f"the pin of {key}")
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
        self._atomic_write(self._pins / key, b"", f"the pin of {key}")

    def unpin(self, cid: str | CID) -> None:
        key = cid_key(cid)
        try:
            (self._pins / key).unlink()
        except FileNotFoundError:
            raise NotFound(key, "not pinned") from None

    def pins(self) -> list[str]:
        """The pinned CIDs: regular files of ``pins/`` named by a canonical CIDv1, the names
        :meth:`pin` writes. Anything else there (a stray file, a pin named in another spelling
        that :meth:`unpin` would not find) is no pin: skipped and logged once, so callers that
        parse the list get CIDs only."""
        try:
            entries = list(os.scandir(self._pins))
        except OSError as e:
            raise StoreUnavailable(str(self.root), f"cannot list pins: {e}", 5.0) from e
        return sorted(e.name for e in entries if self._is_cid_file(e, "pins"))

    def blocks(self) -> list[str]:
        """CIDs of all stored blocks (for inspection and tests); like :meth:`pins`, files whose
        name is not a canonical CIDv1 are skipped."""
        return sorted(
            e.name
            for d in os.scandir(self._blocks)
            if d.is_dir(follow_symlinks=False)
            for e in os.scandir(d.path)
            if self._is_cid_file(e, "blocks")
        )

    def _is_cid_file(self, entry: os.DirEntry[str], where: str) -> bool:
        """Whether ``entry`` is a regular file named by a canonical CIDv1; a visible entry
        that is not is logged (once per name and store). Temp files (hidden) are skipped
        silently: they are writes in progress or leftovers the next open removes."""
        name = entry.name
        if name.startswith("."):
            return False
        try:
            canonical = cid_key(name)
        except InvalidCID:
            canonical = None
        try:
            regular = entry.is_file(follow_symlinks=False)
        except OSError:
            regular = False
        if canonical == name and regular:
            return True
        if name not in self._not_cids:
            self._not_cids.add(name)
            why = (
                "not a regular file" if canonical == name
                else "not a CID" if canonical is None
                else f"not the canonical spelling of its CID ({canonical})"
            )
            log.warning("store %s: ignoring %s/%s: %s", self.root, where,
                        os.path.relpath(entry.path, self.root / where), why)
        return False

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
