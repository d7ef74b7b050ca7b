"""DAGs built to cost memory rather than bytes are refused early (dag.read_file)."""

from __future__ import annotations

import random

import pytest

from backend.store import ContentTooLarge, InvalidContent
from backend.store.cid import CID, DAG_PB, RAW
from backend.store.dag import (
    CHUNK_SIZE,
    MAX_READ_LINKS,
    UNIXFS_FILE,
    UnixFSData,
    build_dag,
    encode_pbnode,
    iter_chunks,
    read_file,
)


def _node(blocks: dict[CID, bytes], links: list[tuple[CID, int]]) -> CID:
    sizes = [size for _, size in links]
    block = encode_pbnode(links, UnixFSData(UNIXFS_FILE, None, sum(sizes), sizes).encode())
    cid = CID.for_block(block, DAG_PB)
    blocks[cid] = block
    return cid


def _counting(blocks: dict[CID, bytes]) -> tuple[dict[str, int], object]:
    reads = {"n": 0}

    def get(cid: CID, _limit: int) -> bytes:
        reads["n"] += 1
        return blocks[cid]

    return reads, get


def test_a_node_with_more_links_than_any_importer_makes_is_refused() -> None:
    blocks: dict[CID, bytes] = {}
    leaf = CID.for_block(b"x" * 20_000, RAW)
    blocks[leaf] = b"x" * 20_000
    root = _node(blocks, [(leaf, 20_000)] * (MAX_READ_LINKS + 1))
    reads, get = _counting(blocks)
    with pytest.raises(InvalidContent, match=f"more than {MAX_READ_LINKS} links"):
        b"".join(read_file(root, get, max_size=64 * 2**20))  # type: ignore[arg-type]
    assert reads["n"] == 1


def test_a_chain_of_wide_nodes_is_refused_before_its_links_pile_up() -> None:
    """The audit's DAG, scaled down: a chain of distinct nodes, each with many links to a
    1-byte leaf. The first node's links already exceed the blocks the size allows."""
    blocks: dict[CID, bytes] = {}
    leaf = CID.for_block(b"x", RAW)
    blocks[leaf] = b"x"
    top, size = None, 0
    for _ in range(50):
        links = ([(top, size)] if top else []) + [(leaf, 1)] * (MAX_READ_LINKS - 1)
        top = _node(blocks, links)
        size = sum(s for _, s in links)
    reads, get = _counting(blocks)
    with pytest.raises(InvalidContent, match="needs more than .* blocks"):
        b"".join(read_file(top, get, max_size=size))  # type: ignore[arg-type]
    assert reads["n"] == 1


def test_links_declaring_more_bytes_than_the_bound_are_refused_at_once() -> None:
    """A root without a filesize (the early check cannot apply) whose links declare more
    than max_size: refused when the root is read, not after reading max_size bytes."""
    blocks: dict[CID, bytes] = {}
    chunk = b"y" * CHUNK_SIZE
    leaf = CID.for_block(chunk, RAW)
    blocks[leaf] = chunk
    data = UnixFSData(UNIXFS_FILE, None, None, [CHUNK_SIZE] * 10).encode()
    block = encode_pbnode([(leaf, CHUNK_SIZE)] * 10, data)
    root = CID.for_block(block, DAG_PB)
    blocks[root] = block
    reads, get = _counting(blocks)
    with pytest.raises(InvalidContent, match=f"{root} links {10 * CHUNK_SIZE} bytes"):
        b"".join(read_file(root, get, max_size=4 * CHUNK_SIZE))  # type: ignore[arg-type]
    assert reads["n"] == 1


def test_real_files_still_read_at_the_bounds() -> None:
    """A three-level tree (toy chunks of 64 bytes), read with exactly its size as the bound."""
    data = random.Random(1).randbytes(64 * 175 * 2 + 11)
    blocks: dict[CID, bytes] = {}
    root, _ = build_dag(iter_chunks(data, 64), lambda c, b: blocks.__setitem__(c, b))

    def read(max_size: int) -> bytes:
        return b"".join(
            read_file(root, lambda c, _lim: blocks[c], max_size=max_size, min_mean_leaf=64)
        )

    assert read(len(data)) == data
    with pytest.raises(ContentTooLarge):
        read(len(data) - 1)
