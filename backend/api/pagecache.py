"""List pages served again while the index has not moved (issue 7, "Overload").

``GET /api/models`` and ``GET /api/tasks`` read only rows the indexer writes, and the indexer
writes them in the same transaction as its cursor (``index_cursor``). So a page built for one
query at one cursor position is the answer to that query until the cursor moves: the cache key
is the request's path and the query parameters its route declares, and an entry is valid while
the cursor is where it was (one indexed read per request instead of the count, the page query
and the encoding). Pages are built from plain column rows and encoded once with pydantic-core's
encoder (the routes' ``*Public`` models still document the shape in the OpenAPI, without
re-validating it). Entries
also expire after ``ttl_s`` as a bound on anything written beside the indexer, and the cache
keeps at most ``max_entries`` pages and ``max_bytes`` of them (least recently used go first).
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any

from fastapi import Request
from fastapi.responses import Response
from pydantic_core import to_json
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from backend.db import models as m


class PageCache:
    """Encoded JSON pages by (key, index version), thread-safe, bounded, with a TTL."""

    def __init__(
        self, ttl_s: float = 2.0, max_entries: int = 512, max_bytes: int = 32 * 2**20
    ) -> None:
        self.ttl_s = ttl_s
        self.max_entries = max_entries
        self.max_bytes = max_bytes  # a 500-row page is ~240 KB: entries alone do not bound it
        self.size = 0  # bytes of the pages kept
        self._pages: OrderedDict[Hashable, tuple[Any, float, bytes]] = OrderedDict()
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def get(self, key: Hashable, version: Any) -> bytes | None:
        now = time.monotonic()
        with self._lock:
            entry = self._pages.get(key)
            if entry is None or entry[0] != version or now - entry[1] > self.ttl_s:
                self.misses += 1
                return None
            self._pages.move_to_end(key)
            self.hits += 1
            return entry[2]

    def put(self, key: Hashable, version: Any, body: bytes) -> None:
        if len(body) > self.max_bytes:
            return
        with self._lock:
            old = self._pages.pop(key, None)
            if old is not None:
                self.size -= len(old[2])
            self._pages[key] = (version, time.monotonic(), body)
            self.size += len(body)
            while len(self._pages) > self.max_entries or self.size > self.max_bytes:
                _, (_, _, dropped) = self._pages.popitem(last=False)
                self.size -= len(dropped)


def index_version(session: Session) -> tuple[Any, ...]:
    """Where the indexer stands: changes whenever it has written anything."""
    row = session.execute(
        select(
            func.max(m.IndexCursor.block_number),
            func.max(m.IndexCursor.log_index),
            func.max(m.IndexCursor.updated_at),
            func.count(),
        )
    ).one()
    return tuple(row)


def cached_page(request: Request, session: Session, build: Callable[[], Any]) -> Response:
    """The JSON page for this request: from the app's :class:`PageCache` when the index has not
    moved since it was built, else ``build()`` encoded once and kept."""
    cache: PageCache | None = getattr(request.app.state, "page_cache", None)
    if cache is None:
        return Response(to_json(build()), media_type="application/json")
    key = (request.url.path, _declared_query(request))
    version = index_version(session)
    body = cache.get(key, version)
    if body is None:
        body = to_json(build())
        cache.put(key, version, body)
    return Response(body, media_type="application/json")


def _declared_query(request: Request) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """The query parameters the route declares, by name, each with its values in the order
    sent: parameters it ignores (``?junk=1``, ``?junk=2``, ...) must not make new cache keys
    that evict every real page. The order of a repeated parameter's values is kept: the route
    reads the last one, so ``?status=open&status=closed`` and ``?status=closed&status=open``
    are two queries (sorted as pairs they shared one key, and one page)."""
    params = request.query_params
    route = request.scope.get("route")
    dependant = getattr(route, "dependant", None)
    names = (
        set(params.keys()) if dependant is None else {p.alias for p in dependant.query_params}
    )
    return tuple((name, tuple(params.getlist(name))) for name in sorted(names) if name in params)
