"""Held-out pass on the embedded store's files: temp files left by interrupted writes, and
names in ``pins/`` and the block shards that are not CIDs."""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path

import pytest

from backend.store import EmbeddedStore, compute_cid
from backend.store import embedded as embedded_module
from backend.store.embedded import STALE_TEMP_S, TEMP_PREFIX


def _age(path: Path, seconds: float) -> Path:
    """Set ``path``'s modification time ``seconds`` in the past."""
    then = time.time() - seconds
    os.utime(path, (then, then))
    return path


def test_temp_files_of_interrupted_writes_are_removed_when_the_store_opens(
    tmp_path: Path,
) -> None:
    """A write killed between mkstemp and the rename left ``.tmp-*`` files forever. Opening
    removes the old ones; a young one (another process writing now) and everything that is
    not a temp file stay."""
    store = EmbeddedStore(tmp_path / "s", fsync=False)
    cid = store.add(b"a block that stays")
    shard = store.block_path(cid).parent
    dead_block = shard / f"{TEMP_PREFIX}dead1"
    dead_block.write_bytes(b"half a block")
    _age(dead_block, STALE_TEMP_S + 60)
    dead_pin = store.root / "pins" / f"{TEMP_PREFIX}dead2"
    dead_pin.write_bytes(b"")
    _age(dead_pin, STALE_TEMP_S + 60)
    live = shard / f"{TEMP_PREFIX}live"  # a writer in another process, between write and rename
    live.write_bytes(b"being written")
    not_ours = shard / f"{TEMP_PREFIX}dir"  # not a regular file: never touched
    not_ours.mkdir()
    _age(not_ours, STALE_TEMP_S + 60)
    other = store.root / "pins" / "notes.txt"
    other.write_text("not a temp file")
    _age(other, STALE_TEMP_S + 60)

    reopened = EmbeddedStore(store.root, fsync=False)

    assert sorted(reopened.removed_temp_files) == sorted([dead_block, dead_pin])
    assert not dead_block.exists() and not dead_pin.exists()
    assert live.read_bytes() == b"being written"
    assert not_ours.is_dir() and other.is_file()
    assert reopened.get(cid) == b"a block that stays"
    assert EmbeddedStore(store.root, fsync=False, stale_temp_s=0).removed_temp_files == [live]


def test_a_bad_grace_period_is_refused_naming_it(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="stale_temp_s"):
        EmbeddedStore(tmp_path / "s", stale_temp_s=float("nan"))


def test_a_writer_whose_temp_file_was_removed_as_stale_writes_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A writer stopped past the grace period (SIGSTOP, swapped out) finds its temp file
    removed by a store opening in another process: it writes the block again instead of
    failing the upload."""
    store = EmbeddedStore(tmp_path / "s", fsync=False)
    real_replace = os.replace
    swept: list[str] = []

    def sweep_first(src: str, dst: str) -> None:
        if not swept:  # another process's open removes the temp file before the rename
            swept.append(src)
            os.unlink(src)
        real_replace(src, dst)

    monkeypatch.setattr(embedded_module.os, "replace", sweep_first)
    data = b"written by a slow writer"
    cid = store.add(data)
    assert swept and cid == compute_cid(data)
    assert store.get(cid) == data and store.pins() == [cid]
    assert not list(store.root.rglob(f"{TEMP_PREFIX}*"))


def test_pins_lists_only_files_named_by_a_canonical_cid(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A stray file in ``pins/`` showed up as a pin (and broke callers parsing the list); so
    did a CID in another spelling, which ``unpin`` cannot find. They are skipped and named in
    the log once."""
    store = EmbeddedStore(tmp_path / "s", fsync=False)
    cid = store.add(b"pinned")
    pins = store.root / "pins"
    (pins / "README").write_text("stray")
    qm = "QmYwAPJzv5CZsnA625s3Xf2nemtYgPpHdWEz79ojWnPbdG"  # a CIDv0: pin() never writes it
    (pins / qm).write_bytes(b"")
    other = compute_cid(b"other")
    (pins / other).mkdir()  # a directory is no pin file
    with caplog.at_level(logging.WARNING, logger="backend.store.embedded"):
        assert store.pins() == [cid]
        assert store.pins() == [cid]
    assert caplog.text.count("pins/README: not a CID") == 1
    assert f"pins/{qm}: not the canonical spelling" in caplog.text
    assert f"pins/{other}: not a regular file" in caplog.text


def test_blocks_lists_only_files_named_by_a_canonical_cid(tmp_path: Path) -> None:
    store = EmbeddedStore(tmp_path / "s", fsync=False)
    cid = store.add(b"one block")
    (store.block_path(cid).parent / "core.1234").write_bytes(b"a stray file")
    assert store.blocks() == [cid]
