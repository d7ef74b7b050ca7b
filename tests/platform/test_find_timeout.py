"""A node that times out finding a CID is an outage, not a missing CID: the store raises
``FindTimeout`` (still a ``NotFound`` for callers that treat both alike), the daemon retries
it (``Transient``) saying "timed out", and neither declines the offer nor gives the task back.
The node here is a fake IPFS RPC API (httpx transport) over an embedded store, answering as
Kubo does when its ``timeout`` runs out."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import httpx
import pytest
import torch

from backend.chain.platform import OfferState
from backend.store import CID, EmbeddedStore, FindTimeout, IpfsRpcStore, NotFound
from backend.store.bundle import read_bundle, upload_model
from workers.daemon.handler import OfferHandler, Transient

from .helpers import TINY_SPEC, post_task

torch.set_num_threads(1)
EXPERT = Path(__file__).resolve().parents[2] / "models" / "odmtl-2a"
READS = ("get", "iter_get", "get_to_file", "get_block", "has")


class FakeNode:
    """An IPFS node's ``block/get`` over ``blocks``; CIDs in ``lost`` time out as Kubo says
    when the provider is offline, unknown ones are "not found"."""

    def __init__(self, blocks: EmbeddedStore) -> None:
        self.blocks, self.lost = blocks, set()

    def __call__(self, request: httpx.Request) -> httpx.Response:
        cid = CID.parse(request.url.params["arg"])
        if str(cid.v1()) in self.lost:
            return httpx.Response(500, json={"Message": "context deadline exceeded", "Code": 0,
                                             "Type": "error"})
        try:
            return httpx.Response(200, content=self.blocks._read_block(cid, 2**30))
        except NotFound:
            return httpx.Response(500, json={"Message": "block was not found locally (offline)",
                                             "Code": 0, "Type": "error"})


class ThroughNode:
    """The worker's store: reads through the fake node's RPC API, writes to the embedded store
    behind it (the outcome's upload is not what is tested here)."""

    def __init__(self, blocks: EmbeddedStore, node: FakeNode) -> None:
        self.blocks = blocks
        self.rpc = IpfsRpcStore("http://ipfs.test:5001", retries=0, find_timeout=1.0,
                                transport=httpx.MockTransport(node))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.rpc if name in READS else self.blocks, name)


def handler_for(p, worker: str, store: Any, tmp_path: Path) -> OfferHandler:  # noqa: ANN001
    h = OfferHandler(account=p.chain._keys[worker], platform=p, store=store,
                     data_dir=tmp_path / "w" / worker)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    return h


def test_the_store_tells_a_find_timeout_from_content_not_found(tmp_path: Path) -> None:
    blocks = EmbeddedStore(tmp_path / "ipfs")
    node = FakeNode(blocks)
    store = ThroughNode(blocks, node).rpc
    cid = blocks.add(b"a task spec")
    assert store.get(cid) == b"a task spec"
    node.lost.add(cid)
    with pytest.raises(FindTimeout) as err:
        store.get(cid)
    assert "timed out finding" in str(err.value) and "not found" not in str(err.value)
    assert cid in str(err.value) and "context deadline exceeded" in str(err.value)
    assert isinstance(err.value, NotFound)  # callers that treat both alike keep working
    assert store.has(cid) is False
    absent = blocks.key("bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy")
    with pytest.raises(NotFound) as err:
        store.get(absent)
    assert not isinstance(err.value, FindTimeout)


def test_a_spec_that_times_out_is_retried_not_declined(env, tmp_path: Path) -> None:
    p, actors, blocks = env
    node = FakeNode(blocks)
    task_id, offered, spec_cid = post_task(p, blocks, actors.requester)
    h = handler_for(p, offered[0], ThroughNode(blocks, node), tmp_path)
    node.lost.add(spec_cid)
    with pytest.raises(Transient, match="timed out finding") as err:
        h.handle(task_id, offered[0])
    assert "not found" not in str(err.value)
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.OFFERED  # not declined
    assert h._state(task_id)["phase"] == "offered"  # recover() queues it again while it lives
    node.lost.clear()  # the provider is back: the retry takes the offer
    assert h.handle(task_id, offered[0])["status"] == "submitted"


def test_expert_weights_that_time_out_are_retried_before_and_after_acceptance(
    env, tmp_path: Path
) -> None:
    """Before accepting, a timeout is no decline; after accepting (redelivered, the experts
    not fetched yet), no job failed on chain: both are retried."""
    p, actors, blocks = env
    node = FakeNode(blocks)
    cid = upload_model(blocks, EXPERT)
    weights, _ = read_bundle(blocks, cid)["model.safetensors"]
    spec = {**TINY_SPEC, "experts": [cid], "budget": {"steps": 200}}
    task_id, offered, _ = post_task(p, blocks, actors.requester, spec=spec)
    h = handler_for(p, offered[0], ThroughNode(blocks, node), tmp_path)
    node.lost.add(str(CID.parse(weights).v1()))
    with pytest.raises(Transient, match="timed out finding") as err:
        h.handle(task_id, offered[0])
    assert "not in the store" not in str(err.value)
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.OFFERED

    t2, offered2, _ = post_task(p, blocks, actors.requester,
                                spec={**spec, "seed": 8}, num_workers=3)
    assert offered[0] in offered2
    p.tmc.transact("acceptOffer", t2, sender=offered[0])  # accepted, then the daemon restarted
    with pytest.raises(Transient, match="timed out finding"):
        h.handle(t2, offered[0])
    assert p.tmc.offer(t2, offered[0])["state"] == OfferState.ACCEPTED  # not given back
    st = h._state(t2)
    assert st.get("phase") != "failed" and st["starts_without_progress"] == 0, st
    node.lost.clear()
    assert h.handle(t2, offered[0])["status"] == "submitted"
    assert json.loads((h.job_dir(t2) / "state.json").read_text())["phase"] == "submitted"
