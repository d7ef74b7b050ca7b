"""The worker daemon's Prometheus endpoint: jobs by phase and training speed read from the job
directories, chain request latency, served over real HTTP."""

from __future__ import annotations

import json
from pathlib import Path

import httpx
from eth_tester import EthereumTester
from web3 import EthereumTesterProvider, Web3

from drlaas.commands.up import free_port
from tests.backend.test_observability import sample
from workers.daemon.metrics import WorkerMetrics, last_points


def job(root: Path, name: str, phase: str, points: list[dict[str, float]] = ()) -> None:
    d = root / name
    d.mkdir(parents=True)
    (d / "state.json").write_text(json.dumps({"phase": phase}))
    if points:
        (d / "progress.jsonl").write_text("".join(json.dumps(p) + "\n" for p in points))


def test_worker_metrics_over_http(tmp_path: Path) -> None:
    root = tmp_path / "jobs"
    job(root, "1", "submitted")
    job(root, "2", "declined")
    job(root, "3", "accepted", [{"step": 0, "wall_time": 1.0}, {"step": 500, "wall_time": 3.0}])
    (root / "3" / "run" / "checkpoint").mkdir(parents=True)  # the trainer's own state file
    (root / "3" / "run" / "checkpoint" / "state.json").write_text('{"update": 4}')
    metrics = WorkerMetrics(root)
    w3 = Web3(EthereumTesterProvider(EthereumTester()))
    metrics.instrument(w3)
    server = metrics.serve(free_port())
    try:
        url = f"http://127.0.0.1:{server.server_port}/metrics"
        text = httpx.get(url).text
        assert sample(text, "drlaas_worker_jobs", phase="submitted") == 1
        assert sample(text, "drlaas_worker_jobs", phase="accepted") == 1
        assert 'drlaas_worker_jobs{phase="unknown"}' not in text
        assert sample(text, "drlaas_worker_training_steps_per_second", job="3") == 250.0
        assert sample(text, "drlaas_worker_training_step", job="3") == 500
        chain = {"method": "eth_blockNumber", "outcome": "ok"}
        calls = sample(text, "drlaas_chain_request_duration_seconds_count", **chain)
        assert w3.eth.block_number >= 0
        # training goes on, a job finishes, the daemon asks the chain: the numbers follow
        with (root / "3" / "progress.jsonl").open("a") as f:
            f.write(json.dumps({"step": 1500, "wall_time": 5.0}) + "\n")
        (root / "1" / "state.json").write_text(json.dumps({"phase": "accepted"}))
        text = httpx.get(url).text
        assert sample(text, "drlaas_worker_training_steps_per_second", job="3") == 500.0
        assert sample(text, "drlaas_worker_jobs", phase="accepted") == 2
        assert 'drlaas_worker_jobs{phase="submitted"}' not in text
        assert sample(text, "drlaas_chain_request_duration_seconds_count", **chain) == calls + 1
    finally:
        server.shutdown()
        server.server_close()


def test_last_points_reads_only_the_tail(tmp_path: Path) -> None:
    f = tmp_path / "progress.jsonl"
    f.write_text("".join(json.dumps({"step": i, "pad": "x" * 300}) + "\n" for i in range(100)))
    assert [p["step"] for p in last_points(f)] == [98, 99]
    assert last_points(tmp_path / "missing.jsonl") == []
