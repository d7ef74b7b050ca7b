"""Prometheus metrics of the gateway, ``GET /metrics`` (text exposition format).

* ``drlaas_http_request_duration_seconds{method,route,status}``: latency by route *template*
  (``/api/tasks/{task_id}``, never the raw path, so the label set stays bounded);
* ``drlaas_http_errors_total{method,route,kind}``: 4xx (``client``) and 5xx or unhandled
  exceptions (``server``);
* ``drlaas_chain_request_duration_seconds{method,outcome}``: every JSON-RPC request the gateway
  makes to its chain (a web3 middleware; the worker daemon uses the same one);
* ``drlaas_tasks{state}``, ``drlaas_offers{state}``: read from the database index at scrape;
* ``drlaas_queue_depth{queue}``: messages waiting per Celery queue, embedded broker only (a
  read-only SQLite count; Redis/AMQP have their own exporters).

Each app owns its registry (tests and ``drlaas up`` build several apps in one process).
"""

from __future__ import annotations

import logging
import re
import sqlite3
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.responses import Response
from prometheus_client import CollectorRegistry, Counter, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily, Metric
from prometheus_client.registry import Collector
from sqlalchemy import func, select
from sqlalchemy.exc import SQLAlchemyError
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from web3 import Web3
from web3.middleware import Web3Middleware

from backend.db import models as m
from backend.observability.logs import task_context
from backend.settings import Settings

log = logging.getLogger(__name__)

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"
#: Latency buckets (s): loopback API calls are milliseconds, chain writes and uploads seconds.
LATENCY_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30)
UNMATCHED = "<unmatched>"
#: Requests about one task carry its id into the logs (``task_id`` of JSON lines).
_TASK_PATH = re.compile(r"^/api/tasks/(\d{1,19})(?:/|$)")


def chain_latency_middleware(histogram: Histogram) -> type[Web3Middleware]:
    """A web3 middleware class timing each JSON-RPC request into ``histogram`` (labels
    ``method``, ``outcome`` = ok | error | exception)."""

    class ChainLatency(Web3Middleware):
        def wrap_make_request(self, make_request: Callable[..., Any]) -> Callable[..., Any]:
            def timed(method: Any, params: Any) -> Any:
                t0 = time.perf_counter()
                outcome = "exception"
                try:
                    response = make_request(method, params)
                    failed = isinstance(response, dict) and "error" in response
                    outcome = "error" if failed else "ok"
                    return response
                finally:
                    histogram.labels(method=str(method), outcome=outcome).observe(
                        time.perf_counter() - t0
                    )

            return timed

    return ChainLatency


def chain_histogram(registry: CollectorRegistry) -> Histogram:
    return Histogram(
        "drlaas_chain_request_duration_seconds",
        "JSON-RPC requests to the chain by method and outcome",
        ["method", "outcome"],
        buckets=LATENCY_BUCKETS,
        registry=registry,
    )


def instrument_web3(w3: Web3, histogram: Histogram) -> None:
    """Time ``w3``'s chain requests into ``histogram`` (replacing an earlier instrument: tests
    share one chain between successive apps)."""
    name = "drlaas_chain_latency"
    if name in [n for _, n in w3.middleware_onion.middleware]:
        w3.middleware_onion.remove(name)
    w3.middleware_onion.add(chain_latency_middleware(histogram), name=name)


class IndexCollector(Collector):
    """Tasks and offers by state, counted in the index database at each scrape."""

    def __init__(self, sessions: Callable[[], Any]) -> None:
        self.sessions = sessions

    def collect(self) -> Iterator[Metric]:
        tasks = GaugeMetricFamily("drlaas_tasks", "Tasks in the index by state", labels=["state"])
        offers = GaugeMetricFamily(
            "drlaas_offers", "Offers in the index by state", labels=["state"]
        )
        up = GaugeMetricFamily("drlaas_index_up", "1 when the index database answered the scrape")
        try:
            with self.sessions() as s:
                for family, col in ((tasks, m.TaskRow.status), (offers, m.OfferRow.state)):
                    for state, n in s.execute(select(col, func.count()).group_by(col)):
                        family.add_metric([str(state)], n)
            up.add_metric([], 1)
        except SQLAlchemyError as exc:
            log.warning("metrics: index database unavailable: %s", exc)
            up.add_metric([], 0)
        yield from (tasks, offers, up)


class EmbeddedQueueCollector(Collector):
    """Messages waiting per queue of the embedded (SQLite) broker, read-only."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def collect(self) -> Iterator[Metric]:
        depth = GaugeMetricFamily(
            "drlaas_queue_depth", "Messages waiting in each broker queue", labels=["queue"]
        )
        if self.path.is_file():
            try:
                with sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, timeout=1) as db:
                    rows = db.execute(
                        "SELECT q.name, count(m.id) FROM kombu_queue q LEFT JOIN kombu_message m"
                        " ON m.queue_id = q.id AND m.visible = 1 GROUP BY q.name"
                    ).fetchall()
                for name, n in rows:
                    depth.add_metric([str(name)], n)
            except sqlite3.Error as exc:  # not created yet, or locked past the timeout
                log.debug("metrics: broker not readable: %s", exc)
        yield depth


class GatewayMetrics:
    """The gateway's registry and instruments (see the module docstring)."""

    def __init__(self, sessions: Callable[[], Any], broker_file: Path | None = None) -> None:
        self.registry = CollectorRegistry()
        self.http_latency = Histogram(
            "drlaas_http_request_duration_seconds",
            "HTTP requests by method, route template and status",
            ["method", "route", "status"],
            buckets=LATENCY_BUCKETS,
            registry=self.registry,
        )
        self.http_errors = Counter(
            "drlaas_http_errors",
            "HTTP error responses: kind=client (4xx) or server (5xx, unhandled exceptions)",
            ["method", "route", "kind"],
            registry=self.registry,
        )
        self.chain_latency = chain_histogram(self.registry)
        self.registry.register(IndexCollector(sessions))
        if broker_file is not None:
            self.registry.register(EmbeddedQueueCollector(broker_file))

    def observe(self, method: str, route: str, status: int, seconds: float) -> None:
        self.http_latency.labels(method, route, str(status)).observe(seconds)
        if status >= 400:
            self.http_errors.labels(method, route, "server" if status >= 500 else "client").inc()

    def exposition(self) -> bytes:
        return generate_latest(self.registry)


def route_template(scope: Scope) -> str:
    """The matched route's full path template (``/api/tasks/{task_id}``); ``/`` for the web
    UI's paths, :data:`UNMATCHED` for unknown gateway paths (raw paths would make the label
    set unbounded).

    A route of an included router may know only its own part (``/tasks/{task_id}``): the
    prefix is what precedes that part, filled in with the request's parameters, in the path."""
    template = getattr(scope.get("route"), "path", None)
    path = scope.get("path", "/")
    if isinstance(template, str):
        filled = template
        for name, value in (scope.get("path_params") or {}).items():
            filled = filled.replace("{" + name + "}", str(value)).replace(
                "{" + name + ":path}", str(value)
            )
        return path[: -len(filled)] + template if path.endswith(filled) else template
    first = path.lstrip("/").split("/", 1)[0]
    return UNMATCHED if first in ("api", "rpc") else "/"


class MetricsMiddleware:
    """Pure ASGI middleware: times every HTTP request into :class:`GatewayMetrics` and tags log
    lines of ``/api/tasks/{id}...`` requests with the task id."""

    def __init__(self, app: ASGIApp, metrics: GatewayMetrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        status = 500
        t0 = time.perf_counter()

        async def send_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = int(message["status"])
            await send(message)

        task = _TASK_PATH.match(scope.get("path", ""))
        try:
            with task_context(int(task.group(1)) if task else None):
                await self.app(scope, receive, send_status)
        except Exception:
            status = 500
            raise
        finally:
            self.metrics.observe(
                scope.get("method", "?"), route_template(scope), status, time.perf_counter() - t0
            )


def install_metrics(
    app: FastAPI, settings: Settings, guards: Sequence[Any] = ()
) -> GatewayMetrics:
    """``app.state.metrics``, the timing middleware and ``GET /metrics`` on ``app``, behind
    the FastAPI dependencies ``guards`` (the gateway's token check)."""
    broker = settings.data_dir / "broker.sqlite" if settings.broker_service.embedded else None
    metrics = GatewayMetrics(app.state.sessions, broker)
    app.state.metrics = metrics
    app.add_middleware(MetricsMiddleware, metrics=metrics)


    def scrape() -> Response:
        return Response(metrics.exposition(), media_type=CONTENT_TYPE)

    app.add_api_route(
        "/metrics", scrape, methods=["GET"], include_in_schema=False, dependencies=guards
    )
    return metrics


def metric_names(text: str) -> Iterable[str]:
    """Names of the samples in an exposition (for tests and checks)."""
    for line in text.splitlines():
        if line and not line.startswith("#"):
            yield re.split(r"[{ ]", line, maxsplit=1)[0]
