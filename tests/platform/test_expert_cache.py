"""The models a worker fetches to check an offer (workers/daemon/experts.py): verified bundles
are kept in a content-addressed cache shared by the worker's jobs, so a second offer naming
the same experts downloads nothing; the cache is bounded, least recently used evicted first;
and one offer's check may download only so many bytes, sized from the manifests before any
card or weights is fetched."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
import torch

from backend.chain.platform import OfferState
from backend.store import EmbeddedStore
from backend.store.bundle import add_bundle, read_bundle
from workers.daemon.experts import CACHE_DIR, ModelCache, fetch_experts
from workers.daemon.handler import OfferHandler

from .helpers import TINY_SPEC, post_task

torch.set_num_threads(1)
EXPERT = Path(__file__).resolve().parents[2] / "models" / "odmtl-2a"  # window 5, fits 6x6


def expert(store: EmbeddedStore, name: str) -> str:
    """A bundle of the shipped expert whose card differs by ``name`` (another CID)."""
    card = json.loads((EXPERT / "model.json").read_text()) | {"name": name}
    return add_bundle(store, {"model.safetensors": (EXPERT / "model.safetensors").read_bytes(),
                              "model.json": json.dumps(card).encode()})


def bundle_bytes(store: EmbeddedStore, cid: str) -> int:
    return sum(size for _, size in read_bundle(store, cid).values())


def record_reads(store: EmbeddedStore, monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every CID the store is asked for (``get`` and ``get_to_file`` go through ``iter_get``)."""
    reads: list[str] = []
    real = store.iter_get
    monkeypatch.setattr(store, "iter_get", lambda c, *a, **k: (reads.append(store.key(c)),
                                                                real(c, *a, **k))[1])
    return reads


def handler_for(p, worker: str, store: EmbeddedStore, tmp_path: Path, **kw) -> OfferHandler:  # noqa: ANN001, ANN003
    h = OfferHandler(account=p.chain._keys[worker], platform=p, store=store,
                     data_dir=tmp_path / "w" / worker, **kw)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    return h


def medc(*cids: str, seed: int = 3) -> dict:
    return {**TINY_SPEC, "experts": list(cids), "budget": {"steps": 200}, "seed": seed}


def test_a_second_offer_naming_the_same_experts_downloads_nothing(
    env, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    p, actors, store = env
    a, b = expert(store, "a"), expert(store, "b")
    t1, offered, _ = post_task(p, store, actors.requester, spec=medc(a, b))
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)
    assert h.handle(t1, worker)["status"] == "submitted"
    assert not (h.job_dir(t1) / "experts").exists()  # the finished job's copies are pruned
    cache = h.data_dir / CACHE_DIR
    assert sorted(d.name for d in cache.iterdir()) == sorted([a, b])  # the cache keeps them

    t2, offered2, spec2 = post_task(p, store, actors.requester, spec=medc(b, a, seed=4),
                                    num_workers=3)
    assert worker in offered2
    models = {a, b} | {c for cid in (a, b) for c, _ in read_bundle(store, cid).values()}
    reads = record_reads(store, monkeypatch)
    out = h.handle(t2, worker)
    assert out["status"] == "submitted", out
    assert spec2 in reads and not models & set(reads), reads  # no manifest, card or weights
    card = json.loads((h.job_dir(t2) / "run" / "model" / "model.json").read_text())
    assert [e["ref"] for e in card["training"]["experts"]["experts"]] == [b, a]


def test_the_bytes_one_offer_check_may_download_are_bounded(
    env, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Past the bound the offer is declined on the manifests alone (no card, no weights);
    bundles in the cache do not count, they are not downloaded."""
    p, actors, store = env
    a, b = expert(store, "a"), expert(store, "b")
    one = bundle_bytes(store, a)
    t1, offered, _ = post_task(p, store, actors.requester, spec=medc(a, b))
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path, max_offer_fetch_bytes=one + 100)
    reads = record_reads(store, monkeypatch)
    out = h.handle(t1, worker)
    assert out["status"] == "declined", out
    assert "experts_too_large" in out["reason"] and f"at most {one + 100}" in out["reason"]
    assert p.tmc.offer(t1, worker)["state"] == OfferState.DECLINED
    files = {c for cid in (a, b) for c, _ in read_bundle(store, cid).values()}
    assert not files & set(reads), reads  # manifests only

    fetch_experts(store, [a], tmp_path / "elsewhere", cache=h.cache)  # a is cached now
    t2, offered2, _ = post_task(p, store, actors.requester, spec=medc(a, b, seed=5),
                                num_workers=3)
    assert worker in offered2
    assert h.handle(t2, worker)["status"] == "submitted"


def test_the_cache_is_bounded_and_evicts_the_least_recently_used(
    tmp_path: Path,
) -> None:
    store = EmbeddedStore(tmp_path / "ipfs")
    a, b, c = (expert(store, n) for n in "abc")
    size = bundle_bytes(store, a)
    cache = ModelCache(tmp_path / "cache", max_bytes=2 * size + 1000)
    jobs = tmp_path / "jobs"
    fetch_experts(store, [a], jobs / "1", cache=cache)
    time.sleep(0.05)
    dirs = fetch_experts(store, [b], jobs / "2", cache=cache)
    time.sleep(0.05)
    fetch_experts(store, [a], jobs / "3", cache=cache)  # a used again: b is the oldest now
    time.sleep(0.05)
    fetch_experts(store, [c], jobs / "4", cache=cache)
    assert sorted(d.name for d in cache.root.iterdir()) == sorted([a, c])
    assert cache.size() <= cache.max_bytes
    # a job's files are links of its own: evicting b took nothing from job 2
    assert (dirs[b] / "model.safetensors").read_bytes() == (
        EXPERT / "model.safetensors").read_bytes()
    assert cache.get(b) is None and cache.get(a) is not None
    # a bundle bigger than the whole cache is used, not kept
    small = ModelCache(tmp_path / "small", max_bytes=size // 2)
    assert fetch_experts(store, [a], jobs / "5", cache=small)[a].is_dir()
    assert small.size() == 0
