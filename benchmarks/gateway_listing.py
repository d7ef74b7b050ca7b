"""Gateway listing latency: ``GET /api/models`` over 1,000 indexed models (issue 4).

Inserts ``--models`` indexed model rows (and their owners as workers) into a fresh migrated
SQLite database, then times ``--requests`` GETs through the ASGI app in process (FastAPI
TestClient: routing, validation, SQL, serialisation; no network), cycling through a plain
listing and the search filters (domain, agents, walls, min_reputation, q). Prints p50/p95/max.
Usage: python benchmarks/gateway_listing.py [--models 1000] [--requests 200] [--limit 100]
"""

from __future__ import annotations

import argparse
import random
import statistics
import tempfile
import time
from pathlib import Path

from fastapi.testclient import TestClient
from gateway_load import MODEL_QUERIES as QUERIES  # one list for both listing benchmarks

from backend.api.main import create_app
from backend.db import models as m
from backend.settings import Settings


def populate(sessions, n_models: int, seed: int = 0) -> None:  # type: ignore[no-untyped-def]
    rng = random.Random(seed)
    owners = [f"0x{i:040x}" for i in range(1, 51)]
    with sessions() as s:
        for i, o in enumerate(owners):
            s.add(
                m.WorkerRow(
                    address=o,
                    worker_id=i + 1,
                    domain_mask="1",
                    cpu_cores=4,
                    ram_gb=8,
                    gpu_series=0,
                    status="active",
                    reputation=500_000,
                    rating=500_000,
                    sharing_reputation=rng.randrange(1_000_001),
                    sharing_rating=rng.randrange(1_000_001),
                    block_number=1,
                )
            )
        for i in range(1, n_models + 1):
            agents, lo = rng.randint(1, 5), rng.randint(0, 3)
            hi = lo + rng.randint(0, 2)
            allocs = rng.randint(0, 20)
            s.add(
                m.ModelRow(
                    id=i,
                    owner=rng.choice(owners),
                    domain=rng.randrange(8),
                    cid=f"bafkrei{i:052d}",
                    description=rng.choice(["target", "source", "grid"])
                    + f" localisation model {i}",
                    env=[10, 10, agents, 4, lo, hi],
                    agents=agents,
                    walls_min=lo,
                    walls_max=hi,
                    alloc_count=allocs,
                    total_review=rng.randint(0, 5 * allocs),
                    reputation=rng.randrange(1_000_001),
                    block_number=i,
                )
            )
        s.commit()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", type=int, default=1000)
    ap.add_argument("--requests", type=int, default=200)
    ap.add_argument("--limit", type=int, default=100)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(Settings(data_dir=Path(tmp)), chain=False, indexer_interval=None)
        with TestClient(app) as client:
            populate(app.state.sessions, args.models)
            total = client.get("/api/models", params={"limit": 1}).json()["count"]
            assert total == args.models, total
            for q in QUERIES:  # warm-up (and check every query answers)
                assert (
                    client.get("/api/models", params=q | {"limit": args.limit}).status_code == 200
                )
            # cached: the index stands still, as between two chain events; uncached: every
            # page rebuilt (count, page query, encoding), as right after the indexer wrote
            cached = timed(client, args.requests, args.limit)
            cache, app.state.page_cache = app.state.page_cache, None
            uncached = timed(client, args.requests, args.limit)
            app.state.page_cache = cache
    for name, times in (("page cache", cached), ("no cache", uncached)):
        times.sort()
        print(
            f"GET /api/models over {args.models} models, limit {args.limit}, {args.requests} "
            f"requests ({len(QUERIES)} filter mixes), {name}: p50 {pct(times, 0.50):.1f} ms  "
            f"p95 {pct(times, 0.95):.1f} ms  max {times[-1] * 1e3:.1f} ms  "
            f"mean {statistics.mean(times) * 1e3:.1f} ms"
        )


def pct(times: list[float], f: float) -> float:
    """Percentile ``f`` of sorted ``times``, in ms."""
    return times[min(len(times) - 1, int(f * len(times)))] * 1e3


def timed(client: TestClient, requests: int, limit: int) -> list[float]:
    times = []
    for i in range(requests):
        q = QUERIES[i % len(QUERIES)] | {"limit": limit}
        t0 = time.perf_counter()
        r = client.get("/api/models", params=q)
        times.append(time.perf_counter() - t0)
        assert r.status_code == 200
    return times

if __name__ == "__main__":
    main()
