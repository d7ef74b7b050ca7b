"""Held-out DAGs and store files (third pass, 2026-12-05): UnixFS nodes whose sizes disagree
with what they link, a damaged block file far larger than its block, and the directory
entries a power cut could lose. Each test fails on the code before its fix (its docstring
says what happened then)."""

from __future__ import annotations

import os
import tracemalloc
from pathlib import Path

import pytest

from backend.store import CID, EmbeddedStore, InvalidContent
from backend.store.cid import DAG_PB, RAW
from backend.store.dag import UNIXFS_FILE, UnixFSData, encode_pbnode, read_file


class Blocks(dict):
    """An in-memory block source of hand-made DAGs."""

    def put(self, block: bytes, codec: int) -> CID:
        cid = CID.for_block(block, codec)
        self[cid] = block
        return cid

    def node(self, links: list[tuple[CID, int]], fs: UnixFSData) -> CID:
        return self.put(encode_pbnode(links, fs.encode()), DAG_PB)

    def read(self, root: CID) -> bytes:
        return b"".join(read_file(root, lambda c, n: self[c], max_size=2**20))


def test_a_node_declaring_bytes_it_links_nowhere_is_refused() -> None:
    """A node of inline "abc" with a blocksize of 1,000 and no link (filesize 1,003, the sum
    of its parts) was read as 3 bytes without an error: the blocksize count was checked only
    when the node had links."""
    b = Blocks()
    root = b.node([], UnixFSData(UNIXFS_FILE, b"abc", 1003, [1000]))
    with pytest.raises(InvalidContent, match="0 links but 1 blocksizes"):
        b.read(root)


def test_a_child_without_filesize_must_hold_what_its_parent_says() -> None:
    """A child node without a filesize field under a parent saying 1,000 bytes (the root
    declaring 1,000) linked a 10-byte leaf: the file was read as 10 bytes, no error, as the
    size check compared declarations only."""
    b = Blocks()
    leaf = b.put(b"x" * 10, RAW)
    child = b.node([(leaf, 10)], UnixFSData(UNIXFS_FILE, None, None, [10]))
    root = b.node([(child, 100)], UnixFSData(UNIXFS_FILE, None, 1000, [1000]))
    with pytest.raises(InvalidContent, match="holds 10 bytes but its parent says 1000"):
        b.read(root)
    # a well-formed node may still leave its filesize out
    ok = b.node([(child, 100)], UnixFSData(UNIXFS_FILE, None, None, [10]))
    assert b.read(ok) == b"x" * 10


def test_a_damaged_block_file_is_not_read_whole_when_the_block_is_added_again(
    tmp_path: Path,
) -> None:
    """Adding a block whose file is there checks the copy on disk; it read the whole file, so
    a damaged block file of 64 MiB (here sparse) cost 64 MiB of memory for a 5-byte block.
    The damaged copy is still replaced by the good bytes."""
    store = EmbeddedStore(tmp_path / "s", fsync=False)
    cid = store.add(b"hello")
    path = store.block_path(cid)
    os.truncate(path, 64 * 2**20)
    tracemalloc.start()
    try:
        assert store.add(b"hello") == cid
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 * 2**20, peak
    assert path.read_bytes() == b"hello" and store.get(cid) == b"hello"


def test_a_block_and_its_new_shard_are_flushed_into_their_directories(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A block's file was fsynced but not the rename into its directory, nor a new shard
    directory's entry: after a power cut a block whose CID the caller had recorded (on
    chain) could be missing. Each directory written into is fsynced after the rename."""
    store = EmbeddedStore(tmp_path / "s")
    synced: list[str] = []
    real = os.fsync

    def fsync(fd: int) -> None:
        synced.append(os.readlink(f"/proc/self/fd/{fd}"))
        real(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    cid = store.add(b"power cut")
    shard = store.block_path(cid).parent
    assert str(shard) in synced and str(shard.parent) in synced, synced
    assert str(store.root / "pins") in synced, synced
