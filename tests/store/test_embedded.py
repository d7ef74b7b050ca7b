"""The embedded on-disk store: round trips, pins, corruption and size bounds."""

from __future__ import annotations

import os
import random
from pathlib import Path

import httpx
import pytest

from backend.store import (
    CIDMismatch,
    ContentTooLarge,
    EmbeddedStore,
    IpfsRpcStore,
    NotFound,
    compute_cid,
    make_store,
)
from backend.store.cid import CID, RAW

MiB = 2**20


@pytest.fixture()
def store(tmp_path: Path) -> EmbeddedStore:
    return EmbeddedStore(tmp_path / "store", fsync=False)


@pytest.mark.parametrize("size", [0, 1024, 300 * 1024, 3 * MiB])
def test_round_trip(store: EmbeddedStore, size: int) -> None:
    data = random.Random(size).randbytes(size)
    cid = store.add(data)
    assert cid == compute_cid(data)
    assert store.get(cid) == data
    assert store.has(cid)
    assert cid in store.pins()


def test_add_file_and_get_to_file(store: EmbeddedStore, tmp_path: Path) -> None:
    data = random.Random(1).randbytes(600_000)
    src = tmp_path / "model.safetensors"
    src.write_bytes(data)
    cid = store.add_file(src)
    assert cid == store.add(data)  # idempotent, same CID for bytes or file
    out = tmp_path / "pulled" / "model.safetensors"
    assert store.get_to_file(cid, out) == len(data)
    assert out.read_bytes() == data
    assert not [p for p in out.parent.iterdir() if p.name.endswith(".part")]


def test_multi_chunk_blocks_on_disk(store: EmbeddedStore) -> None:
    data = random.Random(2).randbytes(3 * MiB)
    cid = store.add(data)
    # 12 raw leaves + 1 dag-pb root, each file named by its own CID and hashing to it
    assert len(store.blocks()) == 13
    for key in store.blocks():
        CID.parse(key).verify(store.block_path(key).read_bytes())
    assert CID.parse(cid).codec_name == "dag-pb"
    assert not list(store.root.rglob(".tmp-*"))  # no temp files left behind


def test_corrupted_leaf_on_disk_is_detected(store: EmbeddedStore) -> None:
    data = random.Random(3).randbytes(300 * 1024)
    cid = store.add(data)
    leaves = [k for k in store.blocks() if CID.parse(k).codec == RAW]
    victim = store.block_path(leaves[0])
    raw = bytearray(victim.read_bytes())
    raw[100] ^= 0x01
    victim.write_bytes(bytes(raw))
    with pytest.raises(CIDMismatch, match=leaves[0]):
        store.get(cid)
    # adding the same bytes again repairs the damaged block
    assert store.add(data) == cid
    assert store.get(cid) == data


def test_corrupted_single_block_is_detected(store: EmbeddedStore) -> None:
    cid = store.add(b"hello drlaas\n")
    store.block_path(cid).write_bytes(b"hello DRLaaS\n")
    with pytest.raises(CIDMismatch, match=cid):
        store.get(cid)


def test_corrupted_root_node_is_detected(store: EmbeddedStore) -> None:
    cid = store.add(random.Random(4).randbytes(600_000))
    path = store.block_path(cid)
    raw = bytearray(path.read_bytes())
    raw[-1] ^= 0x01  # last blocksize varint: structure still parses, hash does not match
    path.write_bytes(bytes(raw))
    with pytest.raises(CIDMismatch, match=cid):
        store.get(cid)


def test_missing_block_is_not_found(store: EmbeddedStore) -> None:
    cid = store.add(random.Random(5).randbytes(600_000))
    leaf = next(k for k in store.blocks() if CID.parse(k).codec == RAW)
    store.block_path(leaf).unlink()
    with pytest.raises(NotFound, match=leaf):
        store.get(cid)
    with pytest.raises(NotFound):
        store.get(compute_cid(b"never added"))


def test_oversize_is_refused_both_ways(tmp_path: Path) -> None:
    small = EmbeddedStore(tmp_path / "s", max_size=500_000, fsync=False)
    with pytest.raises(ContentTooLarge, match="500001 bytes > limit of 500000"):
        small.add(b"\0" * 500_001)
    assert small.blocks() == []  # refused before anything was written
    big = random.Random(6).randbytes(600_000)
    src = tmp_path / "big.bin"
    src.write_bytes(big)
    with pytest.raises(ContentTooLarge):
        small.add_file(src)
    cid = EmbeddedStore(small.root, fsync=False).add(big)  # written by a store with a larger bound
    with pytest.raises(ContentTooLarge, match="600000 bytes"):
        small.get(cid)
    with pytest.raises(ContentTooLarge):
        small.get(cid, max_size=1000)


def test_pins(store: EmbeddedStore) -> None:
    a = store.add(b"a", pin=False)
    b = store.add(b"b")
    assert store.pins() == [b]
    store.pin(a)
    assert store.pins() == sorted([a, b])
    store.unpin(b)
    assert store.pins() == [a]
    with pytest.raises(NotFound):
        store.unpin(b)
    with pytest.raises(NotFound):
        store.pin(compute_cid(b"absent"))


def test_two_stores_share_a_directory(tmp_path: Path) -> None:
    """Gateway and workers open the same directory from different processes."""
    one = EmbeddedStore(tmp_path / "shared", fsync=False)
    two = EmbeddedStore(tmp_path / "shared", fsync=False)
    cid = one.add(b"model bytes")
    assert two.get(cid) == b"model bytes"


def test_make_store_specs(tmp_path: Path) -> None:
    assert isinstance(make_store(f"embedded:{tmp_path / 'a'}"), EmbeddedStore)
    assert make_store("embedded", default_dir=tmp_path / "b").root == (tmp_path / "b").resolve()  # type: ignore[attr-defined]
    assert isinstance(make_store(str(tmp_path / "c")), EmbeddedStore)
    assert isinstance(make_store(tmp_path / "d"), EmbeddedStore)
    assert isinstance(make_store(f"file://{tmp_path / 'e'}"), EmbeddedStore)
    rpc = make_store("/ip4/127.0.0.1/tcp/5001")
    assert isinstance(rpc, IpfsRpcStore) and rpc.url == "http://127.0.0.1:5001/api/v0"
    assert make_store("http://h:5001/api/v0/").url == "http://h:5001/api/v0"  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match="default_dir"):
        make_store("embedded")
    with pytest.raises(ValueError, match="ftp://x"):
        make_store("ftp://x")
    assert not os.path.exists("embedded")


def test_a_quick_copy_of_a_node_store_tells_the_node_to_give_up_sooner(
    store: EmbeddedStore,
) -> None:
    """``with_find_timeout`` (the indexer's spec reads): the node is asked to stop looking for
    an absent CID after the shorter time, never after a longer one than the store's, and the
    original store keeps its own; an embedded store never searches and is its own copy."""
    asked: list[str | None] = []

    def node(request: httpx.Request) -> httpx.Response:
        asked.append(request.url.params.get("timeout"))
        return httpx.Response(500, json={"Message": "context deadline exceeded", "Code": 0})

    rpc = IpfsRpcStore("http://node:5001", retries=0, transport=httpx.MockTransport(node))
    missing = compute_cid(b"nobody has this")
    with pytest.raises(NotFound, match="within 2 s"):
        rpc.with_find_timeout(2.0).get(missing)
    with pytest.raises(NotFound, match="within 10 s"):
        rpc.with_find_timeout(60.0).get(missing)
    with pytest.raises(NotFound, match="within 10 s"):
        rpc.get(missing)
    assert asked == ["2s", "10s", "10s"]
    with pytest.raises(ValueError, match="> 0"):
        rpc.with_find_timeout(0)
    assert store.with_find_timeout(1.0) is store


def _file_node(links: list[tuple[CID, int]]) -> tuple[CID, bytes]:
    from backend.store.cid import DAG_PB
    from backend.store.dag import UNIXFS_FILE, UnixFSData, encode_pbnode

    sizes = [size for _, size in links]
    data = UnixFSData(UNIXFS_FILE, None, sum(sizes), sizes).encode()
    block = encode_pbnode(links, data)
    return CID.for_block(block, DAG_PB), block


def test_dags_that_cost_blocks_without_bytes_are_refused(store: EmbeddedStore) -> None:
    """A few kB of DAG must not cost millions of reads: links of size 0 (N x N visits of one
    empty leaf) and chains of one-link nodes (a block each, no byte) are refused, naming the
    root, after a bounded number of block reads; real files of any size still read."""
    from backend.store import InvalidContent
    from backend.store.dag import max_blocks

    reads = {"n": 0}
    real = store._read_block

    def counted(cid: CID, max_bytes: int) -> bytes:
        reads["n"] += 1
        return real(cid, max_bytes)

    store._read_block = counted  # type: ignore[method-assign]
    empty = CID.for_block(b"", RAW)
    store._put_block(empty, b"")
    mid, mid_block = _file_node([(empty, 0)] * 300)
    store._put_block(mid, mid_block)
    root, root_block = _file_node([(mid, 0)] * 300)
    store._put_block(root, root_block)
    with pytest.raises(InvalidContent, match=f"{root} links .* size of 0"):
        store.get(str(root), max_size=MiB)
    assert reads["n"] <= 3
    leaf = CID.for_block(b"x", RAW)  # 1 byte under 5,000 one-link nodes
    store._put_block(leaf, b"x")
    top = leaf
    for _ in range(5_000):
        top, block = _file_node([(top, 1)])
        store._put_block(top, block)
    reads["n"] = 0
    with pytest.raises(InvalidContent, match=f"more than {max_blocks(MiB)} blocks"):
        store.get(str(top), max_size=MiB)
    assert reads["n"] == max_blocks(MiB) < 200
    data = random.Random(3).randbytes(3 * MiB + 5)
    assert store.get(store.add(data), max_size=len(data)) == data
