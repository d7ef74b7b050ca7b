"""Gateway listing under load: ``GET /api/models`` and ``GET /api/tasks`` against a real uvicorn
server, driven at fixed request rates by a load generator in a separate process (issue 7).

The parent process fills a fresh SQLite database (``--models`` models and ``--tasks`` tasks,
as the indexer would), starts ``uvicorn`` on a loopback port in a child process (the gateway
app with the chain disabled: listing reads only the database) and, for each path and rate,
runs the generator in another child process. The generator is open-loop: request i is due at
t0 + i / rate whatever happened to earlier ones, and its latency counts from that due time
(so a slow server is not hidden by a generator that waits for it). It keeps up to
``--connections`` HTTP/1.1 keep-alive connections on raw asyncio streams (cheap enough that
one Python process sends 400 requests/s on a loaded 2-core machine).

Prints, per path and rate: requests sent, achieved rate, p50/p95/p99/max latency and the
count of each status (503 = shed by the gateway, -1 = connection error or timeout).
Usage: python benchmarks/gateway_load.py [--rates 100,200,400] [--duration 10]
       [--paths /api/models,/api/tasks] [--models 1000] [--tasks 1000] [--limit 100]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import random
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
MODEL_QUERIES = [
    {},
    {"domain": 3},
    {"agents": 3},
    {"walls": 2},
    {"min_reputation": 0.6},
    {"q": "target"},
    {"domain": 1, "agents": 2, "sort": "newest"},
    {"sort": "allocations", "offset": 500},
]
TASK_QUERIES = [
    {},
    {"status": "open"},
    {"domain": 2},
    {"status": "completed", "domain": 1},
    {"offset": 500},
]


# -- server side ----------------------------------------------------------------------------
def serve_app() -> Any:
    """uvicorn factory: the gateway from DRLAAS_* settings, no chain, no indexer thread."""
    from backend.api.main import create_app
    from backend.settings import load_settings

    return create_app(load_settings(), chain=False, indexer_interval=None)


def populate(data_dir: Path, n_models: int, n_tasks: int, seed: int = 0) -> None:
    """Migrate a fresh database in ``data_dir`` and insert the listed rows."""
    sys.path.insert(0, str(HERE))
    from fastapi.testclient import TestClient
    from gateway_listing import populate as populate_models

    from backend.api.main import create_app
    from backend.db import models as m
    from backend.settings import Settings

    app = create_app(Settings(data_dir=data_dir), chain=False, indexer_interval=None)
    with TestClient(app):
        populate_models(app.state.sessions, n_models, seed)
        rng = random.Random(seed + 1)
        requesters = [f"0x{i:040x}" for i in range(100, 120)]
        with app.state.sessions() as s:
            for i in range(1, n_tasks + 1):
                s.add(
                    m.TaskRow(
                        id=i,
                        requester=rng.choice(requesters),
                        domain=rng.randrange(8),
                        status=rng.choice(["open", "completed", "cancelled", "closed"]),
                        num_workers=rng.randint(1, 4),
                        reward_wei=str(10**15),
                        deadline=1_700_000_000 + i,
                        min_reputation=0,
                        min_rating=0,
                        min_cpu_cores=rng.randint(0, 8),
                        min_ram_gb=rng.randint(0, 16),
                        description=f"bafkrei{i:052d}",
                        offered=rng.randint(0, 4),
                        block_number=i,
                        updated_block=i,
                    )
                )
            s.commit()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_server(data_dir: Path, port: int) -> subprocess.Popen[bytes]:
    env = os.environ | {
        "DRLAAS_DATA_DIR": str(data_dir),
        "DRLAAS_MIGRATE_ON_START": "false",
        "PYTHONPATH": os.pathsep.join([str(ROOT), str(HERE)]),
    }
    cmd = [
        sys.executable,
        "-m",
        "uvicorn",
        "--factory",
        "gateway_load:serve_app",
        "--host",
        "127.0.0.1",
        "--port",
        str(port),
        "--log-level",
        "warning",
        "--no-access-log",
    ]
    log = open(data_dir / "server.log", "wb")  # noqa: SIM115 - closed with the process
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"uvicorn exited with {proc.returncode}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return proc
        except OSError:
            time.sleep(0.1)
    proc.kill()
    raise RuntimeError("uvicorn did not start within 60 s")


# -- load generator (runs in its own process) -------------------------------------------------
async def _read_response(reader: asyncio.StreamReader) -> int:
    status_line = await reader.readline()
    if not status_line:
        raise ConnectionError("connection closed")
    status = int(status_line.split()[1])
    length = 0
    while True:
        line = await reader.readline()
        if line in (b"\r\n", b"\n", b""):
            break
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            length = int(value)
    if length:
        await reader.readexactly(length)
    return status


async def generate(
    port: int, targets: list[str], rate: float, duration: float, connections: int, timeout: float
) -> dict[str, Any]:
    loop = asyncio.get_running_loop()
    idle: asyncio.Queue[tuple[asyncio.StreamReader, asyncio.StreamWriter]] = asyncio.Queue()
    opened = 0
    statuses: Counter[int] = Counter()
    latencies: list[float] = []

    async def connection() -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        nonlocal opened
        if idle.empty() and opened < connections:
            opened += 1
            try:
                return await asyncio.open_connection("127.0.0.1", port)
            except OSError:
                opened -= 1
                raise
        return await idle.get()

    async def one(due: float, target: str) -> None:
        nonlocal opened
        status = -1
        conn = None
        try:
            async with asyncio.timeout(timeout):
                conn = await connection()
                conn[1].write(f"GET {target} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
                status = await _read_response(conn[0])
            idle.put_nowait(conn)
        except (OSError, TimeoutError, ValueError, asyncio.IncompleteReadError):
            if conn is not None:
                conn[1].close()
                opened -= 1
        statuses[status] += 1
        latencies.append(loop.time() - due)

    n = int(rate * duration)
    t0 = loop.time() + 0.2
    pending = []
    for i in range(n):
        due = t0 + i / rate
        delay = due - loop.time()
        if delay > 0:
            await asyncio.sleep(delay)
        pending.append(asyncio.create_task(one(due, targets[i % len(targets)])))
    await asyncio.gather(*pending)
    elapsed = loop.time() - t0
    while not idle.empty():
        idle.get_nowait()[1].close()
    latencies.sort()

    def pct(f: float) -> float:
        return latencies[min(len(latencies) - 1, int(f * len(latencies)))] * 1e3

    return {
        "sent": n,
        "rps": n / elapsed,
        "p50_ms": pct(0.50),
        "p95_ms": pct(0.95),
        "p99_ms": pct(0.99),
        "max_ms": latencies[-1] * 1e3,
        "statuses": {str(k): v for k, v in sorted(statuses.items())},
        "connections": opened,
    }


def run_generator(args: argparse.Namespace) -> None:
    targets = json.loads(args.targets)
    out = asyncio.run(
        generate(args.port, targets, args.rate, args.duration, args.connections, args.timeout)
    )
    print(json.dumps(out))


def targets_for(path: str, limit: int) -> list[str]:
    queries = MODEL_QUERIES if path.endswith("/models") else TASK_QUERIES
    return [f"{path}?{urlencode(q | {'limit': limit})}" for q in queries]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", default="100,200,400")
    ap.add_argument("--duration", type=float, default=10.0, help="seconds per rate")
    ap.add_argument("--paths", default="/api/models,/api/tasks")
    ap.add_argument("--models", type=int, default=1000)
    ap.add_argument("--tasks", type=int, default=1000)
    ap.add_argument("--limit", type=int, default=100)
    ap.add_argument("--connections", type=int, default=256)
    ap.add_argument("--timeout", type=float, default=30.0)
    ap.add_argument("--port", type=int, default=0, help="use a running gateway on this port")
    # generator mode (the parent starts this script again with these)
    ap.add_argument("--generate", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--rate", type=float, default=100.0, help=argparse.SUPPRESS)
    ap.add_argument("--targets", default="[]", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.generate:
        run_generator(args)
        return

    with tempfile.TemporaryDirectory() as tmp:
        server = None
        port = args.port
        if not port:
            populate(Path(tmp), args.models, args.tasks)
            port = free_port()
            server = start_server(Path(tmp), port)
        try:
            print(
                f"gateway on 127.0.0.1:{port} (uvicorn, one process); {args.models} models, "
                f"{args.tasks} tasks, limit {args.limit}; {os.cpu_count()} CPUs, load average "
                f"{os.getloadavg()[0]:.2f}"
            )
            print(
                f"{'path':<12} {'rate':>5} {'sent':>6} {'got/s':>7} {'p50 ms':>8} "
                f"{'p95 ms':>8} {'p99 ms':>8} {'max ms':>8}  statuses"
            )
            for path in args.paths.split(","):
                targets = targets_for(path, args.limit)
                for rate in (float(r) for r in args.rates.split(",")):
                    cmd = [
                        sys.executable,
                        __file__,
                        "--generate",
                        "--port",
                        str(port),
                        "--rate",
                        str(rate),
                        "--duration",
                        str(args.duration),
                        "--connections",
                        str(args.connections),
                        "--timeout",
                        str(args.timeout),
                        "--targets",
                        json.dumps(targets),
                    ]
                    res = json.loads(subprocess.run(cmd, capture_output=True, check=True).stdout)
                    print(
                        f"{path:<12} {rate:>5.0f} {res['sent']:>6} {res['rps']:>7.1f} "
                        f"{res['p50_ms']:>8.1f} {res['p95_ms']:>8.1f} {res['p99_ms']:>8.1f} "
                        f"{res['max_ms']:>8.1f}  {res['statuses']}"
                    )
                    time.sleep(1.0)  # let the server drain between runs
        finally:
            if server is not None:
                server.terminate()
                server.wait(timeout=10)
                log = (Path(tmp) / "server.log").read_text(errors="replace")
                print(
                    f"server log: {log.count('Traceback')} tracebacks, "
                    f"{log.count('database pool exhausted')} pool exhaustions"
                )


if __name__ == "__main__":
    main()
