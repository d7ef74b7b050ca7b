"""Clients against hostile HTTP servers (audit R2/R3/R4): every answer the gateway client, the
gateway block reader, the IPFS RPC client and the worker's start-up look-ups read is bounded in
bytes and in time. A hostile server on 127.0.0.1 serves an endless body, a body dripped a byte
at a time, or an endless error body; each client gives up with an error naming the URL and the
bound, soon, having taken little of what the server offered (without the bounds the client
reads all ``OFFER`` bytes, or waits the whole drip, and then fails otherwise or not at all)."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest

from backend.httpbounds import ERROR_BODY_BYTES, ResponseTooLarge, ResponseTooSlow
from backend.settings import load_settings
from backend.store import CID, IpfsRpcStore, StoreError, StoreUnavailable, ipfs_rpc
from backend.store.gateway_blocks import GatewayBlocks
from workers.daemon import links
from workers.daemon.gateway import Gateway, GatewayError

pytestmark = pytest.mark.timeout(60)

OFFER = 64 * 2**20
"""What an endless body offers before the server ends it properly (an unbounded client reads
all of it: the tests then see it failed for another reason, or late)."""
CAP = 2**20
SLACK = 16 * 2**20
"""What may be in flight in socket buffers when a client gives up (loopback buffers)."""
CID_TEXT = str(CID.parse("bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yeq"))


class Hostile:
    """A server whose every request is answered by ``answer(handler)``; counts bytes sent."""

    def __init__(self, answer: Callable[[Any], None]) -> None:
        hostile = self
        self.sent = 0
        self.paths: list[str] = []

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *args: Any) -> None:
                pass

            def _go(self) -> None:
                n = int(self.headers.get("content-length") or 0)
                self.rfile.read(n)
                hostile.paths.append(self.path)
                try:
                    answer(self)
                except (BrokenPipeError, ConnectionResetError):
                    pass

            do_GET = do_POST = _go

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()

    # -- answers -----------------------------------------------------------------------------
    def _chunk(self, h: Any, data: bytes) -> None:
        h.wfile.write(b"%x\r\n%s\r\n" % (len(data), data))
        self.sent += len(data)

    def _start(self, h: Any, code: int) -> None:
        h.send_response(code)
        h.send_header("content-type", "application/json")
        h.send_header("transfer-encoding", "chunked")
        h.end_headers()

    def endless(self, h: Any, code: int = 200) -> None:
        """A JSON array of OFFER bytes, sent as fast as the client takes it."""
        self._start(h, code)
        self._chunk(h, b"[")
        piece = b"0," * 32768
        while self.sent < OFFER:
            self._chunk(h, piece)
        self._chunk(h, b"0]")
        h.wfile.write(b"0\r\n\r\n")

    def drip(self, h: Any, every: float = 0.2, total_s: float = 8.0, code: int = 200) -> None:
        """A JSON object dripped a byte every ``every`` s for ``total_s`` s."""
        self._start(h, code)
        self._chunk(h, b'{"a": 1')
        h.wfile.flush()
        t0 = time.monotonic()
        while time.monotonic() - t0 < total_s:
            time.sleep(every)
            self._chunk(h, b" ")
            h.wfile.flush()
        self._chunk(h, b"}")
        h.wfile.write(b"0\r\n\r\n")
        h.wfile.flush()

    def json(self, h: Any, doc: Any, code: int = 200) -> None:
        data = json.dumps(doc).encode()
        h.send_response(code)
        h.send_header("content-type", "application/json")
        h.send_header("content-length", str(len(data)))
        h.end_headers()
        h.wfile.write(data)
        self.sent += len(data)


@pytest.fixture
def serve() -> Iterator[Callable[[Callable[[Hostile, Any], None]], Hostile]]:
    servers: list[Hostile] = []

    def start(answer: Callable[[Hostile, Any], None]) -> Hostile:
        box: dict[str, Hostile] = {}
        srv = Hostile(lambda h: answer(box["srv"], h))
        box["srv"] = srv
        servers.append(srv)
        return srv

    yield start
    for srv in servers:
        srv.close()


def _within(seconds: float, t0: float) -> None:
    assert time.monotonic() - t0 < seconds, f"took {time.monotonic() - t0:.1f} s"


# -- the gateway client (workers/daemon/gateway.py) -----------------------------------------------
def test_gateway_endless_answer_is_cut_at_the_cap(serve: Any) -> None:
    srv = serve(lambda s, h: s.endless(h))
    t0 = time.monotonic()
    with Gateway(srv.url, timeout=5, max_bytes=CAP) as gw, pytest.raises(ResponseTooLarge) as ei:
        gw.get("/tasks/1")
    _within(10, t0)
    assert srv.url in str(ei.value) and f"cap of {CAP} bytes" in str(ei.value)
    assert srv.sent < CAP + SLACK


def test_gateway_json_rpc_answer_is_cut_at_the_cap(serve: Any) -> None:
    srv = serve(lambda s, h: s.endless(h))
    with Gateway(srv.url, timeout=5, max_bytes=CAP) as gw, pytest.raises(ResponseTooLarge):
        gw.rpc("/rpc", "eth_chainId", [])
    assert srv.sent < CAP + SLACK


def test_gateway_request_may_allow_a_larger_answer(serve: Any) -> None:
    big = ["x" * 1000] * 3000  # ~3 MB of JSON
    srv = serve(lambda s, h: s.json(h, big))
    with Gateway(srv.url, timeout=5, max_bytes=CAP) as gw:
        with pytest.raises(ResponseTooLarge, match="declares"):  # Content-Length says so
            gw.get("/big")
        assert gw.get("/big", max_bytes=4 * CAP) == big


def test_gateway_slow_drip_ends_at_the_deadline(serve: Any) -> None:
    srv = serve(lambda s, h: s.drip(h))
    t0 = time.monotonic()
    with Gateway(srv.url, timeout=0.5) as gw, pytest.raises(ResponseTooSlow) as ei:
        gw.post("/tasks/1/progress", json={"step": 1})
    _within(4, t0)  # deadline 2 x 0.5 s (+ one read); the drip lasts 8 s
    assert "deadline of 1 s" in str(ei.value)


def test_gateway_endless_error_body_is_read_only_in_part(serve: Any) -> None:
    srv = serve(lambda s, h: s.endless(h, code=500))
    t0 = time.monotonic()
    with Gateway(srv.url, timeout=5) as gw, pytest.raises(GatewayError) as ei:
        gw.get("/tasks/1")
    _within(10, t0)
    assert ei.value.status == 500
    assert srv.sent < ERROR_BODY_BYTES + SLACK


# -- the gateway's blocks (backend/store/gateway_blocks.py) ---------------------------------------
def test_gateway_blocks_endless_error_body_is_read_only_in_part(serve: Any) -> None:
    srv = serve(lambda s, h: s.endless(h, code=500))
    t0 = time.monotonic()
    with GatewayBlocks(srv.url, timeout=5) as store, pytest.raises(StoreUnavailable) as ei:
        store.get_block(CID_TEXT, max_bytes=CAP)
    _within(10, t0)
    assert "-> 500" in str(ei.value)
    assert srv.sent < ERROR_BODY_BYTES + SLACK


def test_gateway_blocks_slow_block_ends_at_the_deadline(serve: Any) -> None:
    srv = serve(lambda s, h: s.drip(h))
    t0 = time.monotonic()
    with GatewayBlocks(srv.url, timeout=0.5) as store, pytest.raises(StoreUnavailable) as ei:
        store.get_block(CID_TEXT, max_bytes=CAP)
    _within(4, t0)
    assert "deadline of 1 s" in str(ei.value)


# -- the IPFS RPC client (backend/store/ipfs_rpc.py) ----------------------------------------------
def _ipfs(url: str, **kw: Any) -> IpfsRpcStore:
    return IpfsRpcStore(url, retries=0, backoff=0.01, **kw)


def test_ipfs_endless_error_body_is_read_only_in_part(serve: Any) -> None:
    srv = serve(lambda s, h: s.endless(h, code=500))
    t0 = time.monotonic()
    store = _ipfs(srv.url, timeout=5)
    with pytest.raises(StoreError):
        store.get_block(CID_TEXT, max_bytes=CAP)
    with pytest.raises(StoreError):  # block/stat's error (has)
        store.has(CID_TEXT)
    _within(15, t0)
    assert srv.sent < 2 * (ERROR_BODY_BYTES + SLACK)


def test_ipfs_endless_json_answer_is_cut_at_the_cap(serve: Any, monkeypatch: Any) -> None:
    monkeypatch.setattr(ipfs_rpc, "MAX_ANSWER_BYTES", CAP)
    srv = serve(lambda s, h: s.endless(h))
    t0 = time.monotonic()
    store = _ipfs(srv.url, timeout=5)
    for call in (lambda: store.has(CID_TEXT), lambda: store.add(b"outcome"), store.ping):
        with pytest.raises(StoreError, match=f"past the cap of {CAP} bytes"):
            call()
    _within(15, t0)
    assert srv.sent < 3 * (CAP + SLACK)


def test_ipfs_slow_json_answer_ends_at_the_deadline(serve: Any) -> None:
    srv = serve(lambda s, h: s.drip(h))
    t0 = time.monotonic()
    store = _ipfs(srv.url, timeout=0.5, deadline=1.0)
    with pytest.raises(StoreUnavailable, match="deadline of 1 s"):
        store.add(b"outcome")
    _within(4, t0)


# -- the worker's start-up look-ups (workers/daemon/links.py) -------------------------------------
def test_worker_lookups_are_bounded(serve: Any, tmp_path: Path, monkeypatch: Any) -> None:
    monkeypatch.delenv("DRLAAS_CONTRACTS", raising=False)
    srv = serve(lambda s, h: s.endless(h))
    settings = load_settings(data_dir=str(tmp_path))
    t0 = time.monotonic()
    with pytest.raises(RuntimeError, match="past the cap"):
        links.find_deployment(settings, srv.url)
    _within(10, t0)
    assert srv.sent < 8 * 2**20 + SLACK
