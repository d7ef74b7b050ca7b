"""Held-out gateway pass 6: conditional GETs of content addressed by CID (304 on
``If-None-Match``), a bounded number of queries for the allocation list, and what an anonymous
or unauthorised client found at the edges of the API."""

from __future__ import annotations

import contextlib
import re
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import event

from backend.api.http_limits import MAX_HEAD_BYTES, BoundedHttpToolsProtocol
from backend.api.main import create_app
from backend.db import models as m
from backend.settings import Settings
from backend.store.bundle import add_bundle, bundle_entry

from .conftest import P, serving
from .test_models import card_of, weights_of

ENV = {"rows": 10, "cols": 10, "agents": 2, "walls": [0, 1]}
OWNER = "0x" + "11" * 20


@pytest.fixture
def bare_app(tmp_path: Path) -> FastAPI:
    """A gateway with no chain: its index is filled by hand."""
    return create_app(Settings(data_dir=tmp_path), chain=False)


@pytest.fixture
def bare(bare_app: FastAPI) -> Iterator[TestClient]:
    with TestClient(bare_app) as c:
        yield c


def _model(client: TestClient, model_id: int = 1) -> tuple[str, str]:
    """Index model ``model_id`` with a stored bundle; (bundle CID, weights file CID)."""
    store = client.app.state.store  # type: ignore[attr-defined]
    cid = add_bundle(store, {"model.safetensors": weights_of("w", 100),
                             "model.json": card_of(ENV, "m")})  # fmt: skip
    with client.app.state.sessions() as s:  # type: ignore[attr-defined]
        s.add(m.ModelRow(id=model_id, owner=OWNER, domain=0, cid=cid, description="m",
                         env=[], reputation=0, block_number=1))  # fmt: skip
        s.commit()
    return cid, bundle_entry(store, cid, "model.safetensors")[0]


# -- 1. If-None-Match on blocks and bundle files ---------------------------------------------------


def _matching_forms(cid: str) -> list[str]:
    return [
        f'"{cid}"',
        f'W/"{cid}"',
        "*",
        f'"other", W/"{cid}"',
        f' "a,b" ,, "{cid}" ',  # a comma inside a tag is no separator; empty list elements
    ]


def test_a_block_the_client_holds_is_answered_304_in_every_if_none_match_form(
    bare: TestClient,
) -> None:
    cid = bare.app.state.store.add(b"a block")  # type: ignore[attr-defined]
    url = f"{P}/blocks/{cid}"
    full = bare.get(url)
    assert full.status_code == 200 and full.headers["etag"] == f'"{cid}"'
    for value in _matching_forms(cid):
        for method in ("GET", "HEAD"):
            r = bare.request(method, url, headers={"If-None-Match": value})
            assert r.status_code == 304, (method, value, r.status_code)
            assert r.content == b""
            assert r.headers["etag"] == f'"{cid}"'
            assert r.headers["cache-control"] == full.headers["cache-control"]
            assert "content-length" not in r.headers or r.headers["content-length"] == "0"
            assert "content-type" not in r.headers
    # two header lines are one list
    r = bare.get(url, headers=[("If-None-Match", '"x"'), ("If-None-Match", f'"{cid}"')])
    assert r.status_code == 304


def test_a_block_is_sent_when_if_none_match_names_another_tag_or_is_malformed(
    bare: TestClient,
) -> None:
    cid = bare.app.state.store.add(b"a block")  # type: ignore[attr-defined]
    url = f"{P}/blocks/{cid}"
    for value in ['"other"', cid, f'"{cid}x"', "", "W/", f'junk, "{cid}"', f'"{cid[:-1]}"']:
        r = bare.get(url, headers={"If-None-Match": value})
        assert r.status_code == 200 and r.content == b"a block", value
    # a block the store does not hold is 404 even for a client that says it holds it
    other = bare.app.state.store.add(b"another")  # type: ignore[attr-defined]
    (Path(bare.app.state.store.block_path(other))).unlink()  # type: ignore[attr-defined]
    for value in ("*", f'"{other}"'):
        r = bare.get(f"{P}/blocks/{other}", headers={"If-None-Match": value})
        assert r.status_code == 404 and r.json()["detail"]["rule"] == "content_not_found"


def test_a_model_file_the_client_holds_is_answered_304(bare: TestClient) -> None:
    _, file_cid = _model(bare)
    url = f"{P}/models/1/download"
    full = bare.get(url)
    assert full.status_code == 200 and full.headers["etag"] == f'"{file_cid}"'
    for value in _matching_forms(file_cid):
        for method in ("GET", "HEAD"):
            r = bare.request(method, url, headers={"If-None-Match": value})
            assert r.status_code == 304 and r.content == b"", (method, value)
            assert r.headers["etag"] == f'"{file_cid}"'
            assert "content-disposition" not in r.headers
    # the card has its own CID: the weights' tag does not match it
    r = bare.get(url, params={"file": "model.json"}, headers={"If-None-Match": f'"{file_cid}"'})
    assert r.status_code == 200 and r.json()["name"] == "m"
    # a client at its bound of downloads at once can still revalidate: a 304 takes no slot
    pool = bare.app.state.download_pool  # type: ignore[attr-defined]
    while pool.take("testclient") is None:
        pass
    assert bare.get(url).status_code == 429
    assert bare.get(url, headers={"If-None-Match": f'"{file_cid}"'}).status_code == 304


# -- 2. GET /models/requests: a bounded number of queries ------------------------------------------


def _allocations(client: TestClient, n: int) -> None:
    """Index models 1-3 and ``n`` allocations of two models each."""
    with client.app.state.sessions() as s:  # type: ignore[attr-defined]
        for model_id in (1, 2, 3):
            s.add(m.ModelRow(id=model_id, owner=OWNER, domain=0, cid=f"bafy{model_id}",
                             description="", env=[], reputation=0, block_number=1))  # fmt: skip
        for alloc_id in range(1, n + 1):
            s.add(m.AllocationRow(id=alloc_id, requester=OWNER, domain=0, metric=0,
                                  num_models=2, price_wei="1", block_number=alloc_id))  # fmt: skip
            s.flush()  # the allocation row before its models (their foreign key)
            first, second = 1 + alloc_id % 3, 1 + (alloc_id + 1) % 3
            s.add(m.AllocatedModel(alloc_id=alloc_id, model_id=first, owner=OWNER, qos=10))
            s.add(m.AllocatedModel(alloc_id=alloc_id, model_id=second, owner=OWNER, qos=20,
                                   review=alloc_id % 6))  # fmt: skip
        s.commit()


def _queries(app: FastAPI, request: Any) -> tuple[Any, int]:
    """(``request()``'s response, how many statements the database ran for it)."""
    seen: list[str] = []

    def count(_conn: Any, _cursor: Any, statement: str, *_: Any) -> None:
        seen.append(statement)

    event.listen(app.state.engine, "before_cursor_execute", count)
    try:
        response = request()
    finally:
        event.remove(app.state.engine, "before_cursor_execute", count)
    return response, len(seen)


def test_the_allocation_list_runs_the_same_few_queries_for_any_page_size(
    bare_app: FastAPI, bare: TestClient
) -> None:
    _allocations(bare, 40)
    one, few = _queries(bare_app, lambda: bare.get(f"{P}/models/requests", params={"limit": 1}))
    page, many = _queries(bare_app, lambda: bare.get(f"{P}/models/requests", params={"limit": 40}))
    assert one.status_code == page.status_code == 200
    assert many == few <= 4, (few, many)
    body = page.json()
    assert body["count"] == 40 and [a["alloc_id"] for a in body["data"]] == list(range(40, 0, -1))
    for alloc in body["data"]:  # each allocation with its own models, best QoS first
        i = alloc["alloc_id"]
        assert [x["id"] for x in alloc["models"]] == [1 + (i + 1) % 3, 1 + i % 3]
        assert [x["review"] for x in alloc["models"]] == [i % 6, None]
        assert [x["cid"] for x in alloc["models"]] == [f"bafy{x['id']}" for x in alloc["models"]]
    # the detail route says the same of one allocation
    assert bare.get(f"{P}/models/requests/7").json() == body["data"][40 - 7]


# -- 3. held-out findings -------------------------------------------------------------------------


def test_the_ui_answers_bad_byte_ranges_416_in_the_gateway_error_shape(bare: TestClient) -> None:
    """Starlette answered these 400 in plain text, and refused a range unit it does not know,
    which RFC 9110 (14.2) says a server ignores."""
    whole = bare.get("/index.html")
    size = len(whole.content)
    assert whole.status_code == 200 and size > 10
    for asked, rule in (
        ("bytes=10-0", "range_invalid"),  # inverted
        ("bytes=x-y", "range_invalid"),
        (f"bytes={size}-", "range_not_satisfiable"),
        (f"bytes=0-1, {size + 5}-{size + 9}", "range_not_satisfiable"),
    ):
        for method in ("GET", "HEAD"):
            r = bare.request(method, "/index.html", headers={"Range": asked})
            assert r.status_code == 416, (method, asked, r.status_code)
            assert r.headers["content-range"] == f"bytes */{size}"
            if method == "GET":
                assert r.json()["detail"]["rule"] == rule, asked
                assert asked in r.json()["detail"]["msg"] and str(size) in r.json()["detail"]["msg"]
    for asked in ("items=0-1", "=0-1"):  # a unit the server does not know: ignored
        r = bare.get("/index.html", headers={"Range": asked})
        assert r.status_code == 200 and r.content == whole.content, asked
    # good ranges are still served
    r = bare.get("/index.html", headers={"Range": "bytes=0-3"})
    assert r.status_code == 206 and r.content == whole.content[:4]
    r = bare.get("/index.html", headers={"Range": "bytes=0-1,5-6"})
    assert r.status_code == 206 and r.headers["content-type"].startswith("multipart/byteranges")
    r = bare.get("/index.html", headers={"If-None-Match": whole.headers["etag"]})
    assert r.status_code == 304


@pytest.mark.parametrize(
    "content_type",
    [None, "text/plain", "application/x-www-form-urlencoded", "multipart/form-data; boundary=b",
     "application/jsonx", "application/json, text/plain", ""],
)  # fmt: skip
def test_a_json_body_sent_as_another_type_is_415_naming_the_content_type(
    bare: TestClient, content_type: str | None
) -> None:
    """FastAPI validates such a body as raw bytes: its 422 said "Input should be a valid
    dictionary or object" of the JSON object the client did send."""
    body = b'{"address": "0x' + b"1" * 40 + b'"}'
    headers = {} if content_type is None else {"content-type": content_type}
    r = bare.post(f"{P}/auth/nonce", content=body, headers=headers)
    assert r.status_code == 415, r.text
    detail = r.json()["detail"]
    assert detail["rule"] == "json_content_type" and "application/json" in detail["msg"]
    assert ("no Content-Type" if content_type is None else repr(content_type)) in detail["msg"]


def test_json_bodies_of_json_types_and_missing_bodies_are_as_before(bare: TestClient) -> None:
    body = b'{"address": "0x' + b"1" * 40 + b'"}'
    for kind in ("application/json", "APPLICATION/JSON; charset=utf-8", "application/ld+json"):
        r = bare.post(f"{P}/auth/nonce", content=body, headers={"content-type": kind})
        assert r.status_code == 200, kind
    # no body: the field list names it, whatever the type
    for headers in ({}, {"content-type": "text/plain"}, {"content-type": "application/json"}):
        r = bare.post(f"{P}/auth/nonce", headers=headers)
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body"], headers
    # a JSON body that is not an object stays a validation error
    r = bare.post(f"{P}/auth/nonce", content=b"[1]", headers={"content-type": "application/json"})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body"]


@pytest.mark.parametrize(
    ("method", "path", "allowed"),
    [
        ("PUT", f"{P}/tasks", "GET, HEAD, POST"),  # Starlette said "POST": GET was the other route
        ("OPTIONS", f"{P}/tasks", "GET, HEAD, POST"),
        ("DELETE", f"{P}/models", "GET, HEAD, POST"),
        ("PATCH", f"{P}/models/requests", "GET, HEAD, POST"),
        ("POST", f"{P}/health", "GET, HEAD"),  # HEAD of every GET (HeadAsGet)
        ("GET", f"{P}/tasks/1/cancel", "POST"),
        ("HEAD", f"{P}/tasks/1/cancel", "POST"),
        ("PUT", "/rpc", "POST"),
    ],
)
def test_a_405_allows_every_method_of_the_path(
    bare: TestClient, method: str, path: str, allowed: str
) -> None:
    r = bare.request(method, path)
    assert r.status_code == 405
    assert r.headers["allow"] == allowed
    if method != "HEAD":
        detail = r.json()["detail"]
        assert detail["rule"] == "method_not_allowed"
        assert detail["msg"] == f"{method} is not allowed on {path}; it allows {allowed}"
    # every method it names is served (no 405)
    for other in allowed.split(", "):
        assert bare.request(other, path).status_code != 405, other


@contextlib.contextmanager
def _served(app: FastAPI) -> Iterator[int]:
    """``app`` under uvicorn with the bounded head protocol, as ``drlaas up`` serves it."""
    with serving(app, http=BoundedHttpToolsProtocol) as url:
        yield int(url.rsplit(":", 1)[1])


def _exchange(port: int, request: bytes) -> bytes:
    """Send ``request`` (as much as the server reads) and return all it answers."""
    with socket.create_connection(("127.0.0.1", port), timeout=20) as s:
        with contextlib.suppress(OSError):  # the server may close before it read everything
            s.sendall(request)
        out = b""
        with contextlib.suppress(OSError):
            while chunk := s.recv(65536):
                out += chunk
        return out


@pytest.mark.parametrize(
    "head",
    [
        b"GET /api/health HTTP/1.1\r\nHost: a\r\nX-Big: " + b"a" * (8 * MAX_HEAD_BYTES) + b"\r\n",
        b"GET /api/health HTTP/1.1\r\nHost: a\r\n" + b"X-Many: a\r\n" * MAX_HEAD_BYTES,
        b"GET /api/models?q=" + b"a" * (8 * MAX_HEAD_BYTES) + b" HTTP/1.1\r\nHost: a\r\n",
    ],
    ids=["one long header", "many headers", "long url"],
)
def test_a_request_head_past_the_bound_is_refused_431(bare_app: FastAPI, head: bytes) -> None:
    """httptools kept a head of any size until it ended (200 MB from one anonymous connection
    grew the gateway by 200 MB) and then answered 200."""
    with _served(bare_app) as port:
        answer = _exchange(port, head + b"Connection: close\r\n\r\n")
    status, _, rest = answer.partition(b"\r\n")
    assert status == b"HTTP/1.1 431 Request Header Fields Too Large", answer[:200]
    assert b'"rule": "headers_too_large"' in rest and b"x-content-type-options: nosniff" in rest


def test_bounded_heads_leave_bodies_and_kept_alive_requests_alone(bare_app: FastAPI) -> None:
    big = b'{"address": "0x' + b"1" * 40 + b'", "pad": "' + b"x" * (600 * 1024) + b'"}'
    post = (b"POST /api/auth/nonce HTTP/1.1\r\nHost: a\r\nContent-Type: application/json\r\n"
            b"Content-Length: " + str(len(big)).encode() + b"\r\n\r\n" + big)  # fmt: skip
    near = b"GET /api/health HTTP/1.1\r\nHost: a\r\nX: " + b"a" * (MAX_HEAD_BYTES - 200)
    with _served(bare_app) as port:
        # a body of ten bounds in one write, then two more requests on the connection
        answer = _exchange(port, post + post + near + b"\r\nConnection: close\r\n\r\n")
    statuses = re.findall(rb"HTTP/1\.1 (\d{3}) ", answer)
    assert statuses == [b"422", b"422", b"200"], answer[:300]
