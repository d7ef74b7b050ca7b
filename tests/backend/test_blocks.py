"""``GET /api/blocks/{cid}`` and the client store over it (``GatewayBlocks``): content fetched
block by block through the gateway is verified against its CID on both sides; the docs
redirects; ``/api/local/services`` only for loopback clients."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from backend.api.main import create_app
from backend.settings import Settings
from backend.store import (
    CHUNK_SIZE,
    CIDMismatch,
    FindTimeout,
    NotFound,
    StoreUnavailable,
    compute_cid,
)
from backend.store.bundle import add_bundle, pull_model
from backend.store.gateway_blocks import GatewayBlocks


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path / "data")


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings, chain=False)) as c:
        yield c


def test_content_round_trips_through_the_blocks_endpoint(client: TestClient) -> None:
    data = os.urandom(2 * CHUNK_SIZE + 1234)  # three leaves and a root node
    cid = client.app.state.store.add(data)
    with GatewayBlocks(str(client.base_url), client=client) as remote:
        assert remote.get(cid) == data
        assert remote.has(cid)
        assert not remote.has(compute_cid(b"never stored"))
        with pytest.raises(NotFound):
            remote.get(compute_cid(b"never stored"))


def test_a_model_bundle_pulls_through_the_gateway(client: TestClient, tmp_path: Path) -> None:
    files = {"model.safetensors": os.urandom(5000), "model.json": b'{"env": {}}'}
    cid = add_bundle(client.app.state.store, files)
    with GatewayBlocks(str(client.base_url), client=client) as remote:
        out = pull_model(remote, cid, tmp_path / "pulled")
    assert {n: (out / n).read_bytes() for n in files} == files


def test_block_errors_name_the_rule(client: TestClient, settings: Settings) -> None:
    r = client.get("/api/blocks/aaaaaaaaaa")  # not the CID pattern the route declares
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["path", "cid"]
    r = client.get(f"/api/blocks/{compute_cid(b'absent')}")
    assert r.status_code == 404 and r.json()["detail"]["rule"] == "content_not_found"
    # a block corrupted on disk is refused by the gateway, never served
    cid = client.app.state.store.add(b"soon corrupted")
    client.app.state.store.block_path(cid).write_bytes(b"other bytes")
    r = client.get(f"/api/blocks/{cid}")
    assert r.status_code == 502 and r.json()["detail"]["rule"] == "content_corrupt"


def test_the_reader_verifies_blocks_itself() -> None:
    """A lying gateway (or anything in between) cannot make the reader accept wrong bytes."""
    cid = compute_cid(b"the real content")
    lying = httpx.Client(
        base_url="http://liar",
        transport=httpx.MockTransport(lambda req: httpx.Response(200, content=b"forged")),
    )
    with GatewayBlocks("http://liar", client=lying) as remote, pytest.raises(CIDMismatch):
        remote.get(cid)


def test_docs_paths_redirect_to_the_api_docs(client: TestClient) -> None:
    for alias in ("/docs", "/redoc"):
        r = client.get(alias, follow_redirects=False)
        assert r.status_code == 307 and r.headers["location"] == "/api/docs"
    r = client.get("/docs?target=https://example.com", follow_redirects=False)
    assert r.headers["location"] == "/api/docs"  # no open redirect
    assert "swagger" in client.get("/docs").text.lower()


def test_local_services_only_for_this_machine(settings: Settings) -> None:
    app = create_app(settings, chain=False)
    with TestClient(app) as remote:  # client host "testclient": not loopback
        r = remote.get("/api/local/services")
        assert r.status_code == 404 and r.json()["detail"]["rule"] == "not_local"
    with TestClient(app, client=("127.0.0.1", 5000), base_url="http://127.0.0.1:8000") as local:
        doc = local.get("/api/local/services").json()
    assert doc == {
        "data_dir": str(settings.data_dir),
        "broker_embedded": True,
        "ipfs_dir": str(settings.data_dir / "ipfs"),
    }
    prod = Settings(data_dir=settings.data_dir, mode="production", token_secret="x" * 40)
    with TestClient(create_app(prod, chain=False), client=("127.0.0.1", 5000)) as local:
        assert local.get("/api/local/services").status_code == 404


def test_a_node_that_timed_out_finding_a_block_is_not_absent(
    client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A node's find timeout is a 504 to retry, and a client store over the gateway sees an
    outage (StoreUnavailable: retried by workers), not NotFound (a worker declined the task)."""
    cid = compute_cid(b"held by a provider that is offline")

    def timed_out(cid_: str, max_bytes: int) -> bytes:
        raise FindTimeout(cid_, "context deadline exceeded", after=10)

    monkeypatch.setattr(client.app.state.store, "get_block", timed_out)
    r = client.get(f"/api/blocks/{cid}")
    assert r.status_code == 504, r.text
    assert r.json()["detail"]["rule"] == "content_find_timeout"
    assert "timed out finding" in r.json()["detail"]["msg"] and r.headers["retry-after"]
    with GatewayBlocks(str(client.base_url), client=client) as remote:
        with pytest.raises(StoreUnavailable) as caught:
            remote.get(cid)
    assert not isinstance(caught.value, NotFound)
