"""List pages are served again only while the index stands still (backend/api/pagecache.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from backend.api.main import create_app
from backend.api.pagecache import PageCache
from backend.db import models as m
from backend.settings import Settings


def test_entries_follow_version_ttl_and_size(monkeypatch: pytest.MonkeyPatch) -> None:
    now = [100.0]
    monkeypatch.setattr("backend.api.pagecache.time.monotonic", lambda: now[0])
    cache = PageCache(ttl_s=2.0, max_entries=2)
    cache.put("a", (1,), b"page a at 1")
    assert cache.get("a", (1,)) == b"page a at 1"
    assert cache.get("a", (2,)) is None  # the index moved: never the old page
    now[0] += 2.5
    assert cache.get("a", (1,)) is None  # too old, even at the same version
    cache.put("a", (1,), b"a")
    cache.put("b", (1,), b"b")
    cache.get("a", (1,))  # a is now the most recently used
    cache.put("c", (1,), b"c")
    assert cache.get("b", (1,)) is None and cache.get("a", (1,)) == b"a"


def test_the_cache_is_bounded_in_bytes_too() -> None:
    """A 500-row page is ~240 KB: 512 of them would hold ~120 MB, so bytes are bounded too,
    least recently used out first, and a page larger than the whole bound is not kept."""
    cache = PageCache(max_entries=100, max_bytes=10)
    cache.put("a", (1,), b"aaaa")
    cache.put("b", (1,), b"bbbb")
    cache.put("a", (1,), b"aaaa")  # replaced: counted once
    assert cache.size == 8
    cache.put("c", (1,), b"cccc")  # 12 > 10: b, the least recently used, goes
    assert cache.get("b", (1,)) is None and cache.get("a", (1,)) == b"aaaa"
    assert cache.size == 8
    cache.put("huge", (1,), b"x" * 11)
    assert cache.get("huge", (1,)) is None and cache.size == 8


def test_parameters_the_route_ignores_make_no_new_pages(tmp_path: Path) -> None:
    """``?junk=1``, ``?junk=2``, ...: one page, not one per junk value evicting real ones."""
    app = create_app(Settings(data_dir=tmp_path), chain=False, indexer_interval=None)
    with TestClient(app) as client:
        cache: PageCache = app.state.page_cache
        for i in range(20):
            assert client.get("/api/tasks", params={"limit": 7, "junk": i}).status_code == 200
        assert len(cache._pages) == 1 and cache.hits == 19
        client.get("/api/tasks", params={"limit": 8})  # a declared parameter: its own page
        assert len(cache._pages) == 2


def _model(i: int, owner: str) -> m.ModelRow:
    return m.ModelRow(
        id=i,
        owner=owner,
        domain=0,
        cid=f"bafkrei{i:052d}",
        description=f"model {i}",
        env=[10, 10, 2, 4, 0, 0],
        agents=2,
        walls_min=0,
        walls_max=0,
        alloc_count=0,
        total_review=0,
        reputation=500_000,
        block_number=i,
    )


def _advance_cursor(s, block: int) -> None:  # type: ignore[no-untyped-def]
    for name in ("UsersManager", "TasksManager", "ModelsManager"):
        s.merge(m.IndexCursor(contract=name, address=None, block_number=block, log_index=0))


def test_a_page_is_reused_until_the_indexer_writes(tmp_path: Path) -> None:
    app = create_app(Settings(data_dir=tmp_path), chain=False, indexer_interval=None)
    owner = "0x" + "1" * 40
    with TestClient(app) as client:
        with app.state.sessions() as s:
            s.add(_model(1, owner))
            _advance_cursor(s, 1)
            s.commit()
        cache: PageCache = app.state.page_cache
        first = client.get("/api/models", params={"limit": 10}).json()
        assert [d["id"] for d in first["data"]] == [1]
        hits = cache.hits
        assert client.get("/api/models", params={"limit": 10}).json() == first
        assert cache.hits == hits + 1  # served from the cache
        # another query is another page
        assert client.get("/api/models", params={"limit": 5}).json()["count"] == 1
        # the indexer writes a model and moves its cursor in one transaction: seen at once
        with app.state.sessions() as s:
            s.add(_model(2, owner))
            _advance_cursor(s, 2)
            s.commit()
        again = client.get("/api/models", params={"limit": 10}).json()
        assert sorted(d["id"] for d in again["data"]) == [1, 2] and again["count"] == 2
        assert client.get("/api/tasks").json() == {"data": [], "count": 0}
