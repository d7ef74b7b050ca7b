"""Against a real IPFS node: same CIDs as the embedded store, RPC round trips, a lying node,
size bounds and the node being down."""

from __future__ import annotations

import json
import os
import random
from pathlib import Path

import httpx
import pytest

from backend.store import (
    ADD_PARAMS,
    CIDMismatch,
    ContentTooLarge,
    EmbeddedStore,
    IpfsRpcStore,
    NotFound,
    StoreUnavailable,
    compute_cid,
)
from backend.store.dag import MAX_LINKS

from .conftest import free_port

KiB, MiB = 2**10, 2**20
HELLO_CID = "bafkreidot3j5vvbthwtydmn3ny2pq2ckibhbuj5sech6wpzsxokrkqntsy"


def node_add(url: str, data: bytes, **extra: str) -> str:
    """The node's own CID for ``data``, straight from its API (not through our client)."""
    params = dict(ADD_PARAMS, pin="false", **extra)
    r = httpx.post(f"{url}/api/v0/add", params=params, files={"file": ("f", data)}, timeout=120)
    r.raise_for_status()
    return str(json.loads(r.text.splitlines()[-1])["Hash"])


@pytest.fixture()
def rpc(ipfs_url: str) -> IpfsRpcStore:
    store = IpfsRpcStore(ipfs_url, retries=0, find_timeout=1.0)
    yield store  # type: ignore[misc]
    store.close()


class Tamper(httpx.BaseTransport):
    """A node that lies: forwards to the real node, then alters answers of one endpoint."""

    def __init__(self, endpoint: str, alter) -> None:  # type: ignore[no-untyped-def]
        self.inner = httpx.HTTPTransport()
        self.endpoint = endpoint
        self.alter = alter
        self.calls: list[str] = []

    def handle_request(self, request: httpx.Request) -> httpx.Response:
        response = self.inner.handle_request(request)
        self.calls.append(request.url.path)
        if not request.url.path.endswith(self.endpoint):
            return response
        body = response.read()
        response.close()
        return httpx.Response(response.status_code, content=self.alter(body))


@pytest.mark.parametrize("size", [0, 1 * KiB, 300 * KiB, 3 * MiB])
def test_embedded_cids_equal_the_nodes(ipfs_url: str, tmp_path: Path, size: int) -> None:
    data = random.Random(size).randbytes(size)
    expected = node_add(ipfs_url, data)
    assert compute_cid(data) == expected
    assert EmbeddedStore(tmp_path, fsync=False).add(data) == expected


def test_hello_cid_from_node(ipfs_url: str) -> None:
    assert node_add(ipfs_url, b"hello drlaas\n") == HELLO_CID == compute_cid(b"hello drlaas\n")


def test_two_level_tree_equals_the_nodes(ipfs_url: str) -> None:
    """More than MAX_LINKS leaves (small chunker to keep it fast): the balanced layout's second
    level must match too."""
    from backend.store.dag import build_dag, iter_chunks

    data = random.Random(9).randbytes((MAX_LINKS + 5) * 1024 + 7)
    root, _ = build_dag(iter_chunks(data, 1024))
    assert str(root) == node_add(ipfs_url, data, chunker="size-1024")


@pytest.mark.skipif(
    not os.environ.get("DRLAAS_SLOW_TESTS"), reason="~55 s on js-ipfs; set DRLAAS_SLOW_TESTS=1"
)
def test_three_level_tree_equals_the_nodes(ipfs_url: str) -> None:
    from backend.store.dag import build_dag, iter_chunks

    data = random.Random(174).randbytes(MAX_LINKS * MAX_LINKS * 16 + 48)
    root, _ = build_dag(iter_chunks(data, 16))
    assert str(root) == node_add(ipfs_url, data, chunker="size-16")


@pytest.mark.parametrize("size", [0, 1 * KiB, 300 * KiB, 3 * MiB])
def test_rpc_round_trip(rpc: IpfsRpcStore, size: int) -> None:
    data = random.Random(size + 1).randbytes(size)
    cid = rpc.add(data)
    assert cid == compute_cid(data)
    assert rpc.get(cid) == data
    assert rpc.has(cid)
    assert cid in rpc.pins()
    rpc.unpin(cid)
    assert cid not in rpc.pins()
    rpc.pin(cid)
    assert cid in rpc.pins()


def test_content_moves_between_backends(rpc: IpfsRpcStore, tmp_path: Path) -> None:
    """A CID written by one backend is readable from the other with the same bytes."""
    data = random.Random(11).randbytes(700 * KiB)
    local = EmbeddedStore(tmp_path, fsync=False)
    cid = local.add(data)
    assert rpc.add(local.get(cid)) == cid
    out = tmp_path / "m.bin"
    rpc.get_to_file(cid, out)
    assert out.read_bytes() == data


def test_lying_node_on_download(ipfs_url: str) -> None:
    data = random.Random(12).randbytes(300 * KiB)
    cid = IpfsRpcStore(ipfs_url).add(data)

    def flip(body: bytes) -> bytes:
        return body[:-1] + bytes([body[-1] ^ 1]) if body else b"x"

    liar = IpfsRpcStore(ipfs_url, retries=0, transport=Tamper("block/get", flip))
    with pytest.raises(CIDMismatch, match=cid):
        liar.get(cid)


def test_lying_node_on_upload(ipfs_url: str) -> None:
    def other_cid(body: bytes) -> bytes:
        answer = json.loads(body.splitlines()[-1])
        answer["Hash"] = HELLO_CID
        return json.dumps(answer).encode()

    liar = IpfsRpcStore(ipfs_url, retries=0, transport=Tamper("add", other_cid))
    with pytest.raises(CIDMismatch, match=HELLO_CID):
        liar.add(b"not hello")


def test_oversize_rejected_after_root_block_only(ipfs_url: str) -> None:
    data = random.Random(13).randbytes(3 * MiB)
    cid = IpfsRpcStore(ipfs_url).add(data)
    counting = Tamper("nothing-altered", lambda b: b)
    store = IpfsRpcStore(ipfs_url, max_size=1 * MiB, transport=counting)
    with pytest.raises(ContentTooLarge, match=f"{len(data)} bytes > limit of {MiB}"):
        store.get(cid)
    assert counting.calls == ["/api/v0/block/get"]  # the 12 leaves were never fetched
    with pytest.raises(ContentTooLarge):
        store.add(data)


def test_oversize_single_block_rejected(rpc: IpfsRpcStore) -> None:
    cid = rpc.add(b"\1" * 200 * KiB)
    with pytest.raises(ContentTooLarge):
        rpc.get(cid, max_size=100 * KiB)


def test_missing_content_is_not_found(rpc: IpfsRpcStore) -> None:
    absent = compute_cid(b"never added to the node")
    with pytest.raises(NotFound, match=absent):
        rpc.get(absent)
    assert not rpc.has(absent)


def test_node_down_is_store_unavailable() -> None:
    down = IpfsRpcStore(f"http://127.0.0.1:{free_port()}", retries=2, backoff=0.01)
    for call in (down.ping, lambda: down.get(HELLO_CID), lambda: down.add(b"x"), down.pins):
        with pytest.raises(StoreUnavailable, match="retry in") as info:
            call()
        assert info.value.retry_after > 0


def test_transient_failure_is_retried(ipfs_url: str) -> None:
    """One refused connection, then the node answers: the call succeeds."""

    class FlakyOnce(httpx.BaseTransport):
        def __init__(self) -> None:
            self.inner = httpx.HTTPTransport()
            self.failures = 0

        def handle_request(self, request: httpx.Request) -> httpx.Response:
            if self.failures == 0:
                self.failures += 1
                raise httpx.ConnectError("refused", request=request)
            return self.inner.handle_request(request)

    flaky = FlakyOnce()
    store = IpfsRpcStore(ipfs_url, retries=1, backoff=0.01, transport=flaky)
    assert store.ping()["version"]
    assert flaky.failures == 1
    no_retry = IpfsRpcStore(ipfs_url, retries=0, transport=FlakyOnce())
    with pytest.raises(StoreUnavailable):
        no_retry.ping()
