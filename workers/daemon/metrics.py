"""Prometheus metrics of a worker daemon, served on its own port (``drlaas worker run
--metrics-port N``; Celery workers have no HTTP server of their own).

* ``drlaas_worker_jobs{phase}``: this worker's jobs by phase (offered = being checked,
  accepted = training, trained, uploaded, submitted, declined, failed, closed), read from the
  job directories' ``state.json`` at scrape time, so a restarted daemon reports its jobs at once;
* ``drlaas_worker_training_steps_per_second{job}`` and ``drlaas_worker_training_step{job}``:
  of each job still training, from the last two points of its ``progress.jsonl``;
* ``drlaas_chain_request_duration_seconds{method,outcome}``: the daemon's JSON-RPC requests;
* ``drlaas_worker_offers_found_on_chain_total``: offers the chain offer watcher
  (``workers.daemon.offer_watch``) found on chain and enqueued because the broker had not
  delivered them; ``drlaas_worker_offer_watch_errors_total``: its ticks that failed (node down
  or garbled); ``drlaas_worker_offer_watch_block``: the last block it scanned.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from prometheus_client import CollectorRegistry, start_http_server
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from backend.observability.metrics import chain_histogram, instrument_web3

log = logging.getLogger(__name__)
TRAINING_PHASE = "accepted"
#: Bytes read from the end of ``progress.jsonl`` (a point is ~200 bytes).
TAIL_BYTES = 4096


def last_points(progress: Path, n: int = 2) -> list[dict[str, Any]]:
    """The last ``n`` complete JSON lines of ``progress`` (oldest first); [] if unreadable."""
    try:
        with progress.open("rb") as f:
            f.seek(0, 2)
            size = f.tell()
            f.seek(max(0, size - TAIL_BYTES))
            tail = f.read().decode(errors="replace").splitlines()
    except OSError:
        return []
    if size > TAIL_BYTES:
        tail = tail[1:]  # the first line may be cut
    points = []
    for line in reversed(tail):
        try:
            points.append(json.loads(line))
        except ValueError:
            continue
        if len(points) == n:
            break
    return points[::-1]


def steps_per_second(points: list[dict[str, Any]]) -> float | None:
    """Δstep / Δwall_time of two successive points (None when not measurable, e.g. a resumed
    run whose clock restarted)."""
    if len(points) < 2:
        return None
    try:
        dstep = float(points[-1]["step"]) - float(points[-2]["step"])
        dt = float(points[-1]["wall_time"]) - float(points[-2]["wall_time"])
    except (KeyError, TypeError, ValueError):
        return None
    return dstep / dt if dt > 0 and dstep >= 0 else None


class JobsCollector(Collector):
    """Jobs by phase and training speed, from the job directories under ``root``."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def collect(self) -> Iterator[Metric]:
        jobs = GaugeMetricFamily(
            "drlaas_worker_jobs", "This worker's jobs by phase", labels=["phase"]
        )
        sps = GaugeMetricFamily(
            "drlaas_worker_training_steps_per_second",
            "Environment steps per second of each job in training",
            labels=["job"],
        )
        step = GaugeMetricFamily(
            "drlaas_worker_training_step",
            "Last reported step of each job in training",
            labels=["job"],
        )
        phases: dict[str, int] = {}
        for state_file in sorted(self.root.rglob("state.json")) if self.root.is_dir() else []:
            try:
                doc = json.loads(state_file.read_text())
            except (OSError, ValueError):
                continue
            if not isinstance(doc, dict) or "phase" not in doc:
                continue  # a trainer checkpoint's state.json, not a job's
            if not state_file.parent.name.isdigit():
                continue  # a job directory moved aside (``<task id>.replaced-<time>``)
            phase = str(doc["phase"])
            phases[phase] = phases.get(phase, 0) + 1
            if phase != TRAINING_PHASE:
                continue
            job = state_file.parent.relative_to(self.root).as_posix()
            points = last_points(state_file.parent / "progress.jsonl")
            speed = steps_per_second(points)
            if speed is not None:
                sps.add_metric([job], speed)
            if points:
                step.add_metric([job], float(points[-1].get("step", 0)))
        for phase, n in sorted(phases.items()):
            jobs.add_metric([phase], n)
        yield from (jobs, sps, step)


class OfferWatchCollector(Collector):
    """The counters of a chain offer watcher (an ``offer_watch.OfferWatcher``), read at
    scrape time."""

    def __init__(self, watcher: Any) -> None:
        self.watcher = watcher

    def collect(self) -> Iterator[Metric]:
        found = CounterMetricFamily(
            "drlaas_worker_offers_found_on_chain",
            "Offers found on chain and enqueued because the broker had not delivered them",
        )
        found.add_metric([], float(self.watcher.found))
        errors = CounterMetricFamily(
            "drlaas_worker_offer_watch_errors", "Ticks of the chain offer watcher that failed"
        )
        errors.add_metric([], float(self.watcher.errors))
        yield from (found, errors)
        if self.watcher.block is not None:
            yield GaugeMetricFamily(
                "drlaas_worker_offer_watch_block", "Last block the chain offer watcher scanned",
                value=float(self.watcher.block),
            )


class WorkerMetrics:
    """A daemon's registry: its jobs under ``jobs_root`` and its chain requests."""

    def __init__(self, jobs_root: Path) -> None:
        self.registry = CollectorRegistry()
        self.chain_latency = chain_histogram(self.registry)
        self.registry.register(JobsCollector(jobs_root))

    def watch(self, watcher: Any) -> None:
        """Report the counters of the daemon's chain offer watcher."""
        self.registry.register(OfferWatchCollector(watcher))

    def instrument(self, w3: Any) -> None:
        instrument_web3(w3, self.chain_latency)

    def serve(self, port: int, host: str = "127.0.0.1") -> Any:
        """Serve ``/metrics`` on ``host:port`` from a daemon thread; the HTTP server (its
        ``shutdown()`` stops it)."""
        server, _thread = start_http_server(port, addr=host, registry=self.registry)
        log.info("worker metrics at http://%s:%s/metrics", host, server.server_port)
        return server


def serve_worker_metrics(handler: Any, port: int, host: str = "127.0.0.1") -> WorkerMetrics:
    """Metrics of the daemon running ``handler`` (an OfferHandler), served on ``port``."""
    metrics = WorkerMetrics(Path(handler.data_dir) / "jobs")
    metrics.instrument(handler.platform.chain.w3)
    metrics.serve(port, host)
    return metrics
