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

from backend.api.main import create_app
from backend.db import models as m
from backend.settings import Settings

QUERIES = [
    {},
    {"domain": 3},
    {"agents": 3},
    {"walls": 2},
    {"min_reputation": 0.6},
    {"q": "target"},
    {"domain": 1, "agents": 2, "sort": "newest"},
    {"sort": "allocations", "offset": 500},
]


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
            times = []
            for i in range(args.requests):
                q = QUERIES[i % len(QUERIES)] | {"limit": args.limit}
                t0 = time.perf_counter()
                r = client.get("/api/models", params=q)
                times.append(time.perf_counter() - t0)
                assert r.status_code == 200
    times.sort()
    p = lambda f: times[min(len(times) - 1, int(f * len(times)))] * 1e3  # noqa: E731
    print(
        f"GET /api/models over {args.models} models, limit {args.limit}, {args.requests} requests "
        f"({len(QUERIES)} filter mixes): p50 {p(0.50):.1f} ms  p95 {p(0.95):.1f} ms  "
        f"max {times[-1] * 1e3:.1f} ms  mean {statistics.mean(times) * 1e3:.1f} ms"
    )


if __name__ == "__main__":
    main()
