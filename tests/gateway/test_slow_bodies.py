"""Bodies sent slowly hold nothing: a request counts against the in-flight limit only once its
body is read, and a body not sent in full within ``body_timeout_s`` is answered 408
``body_timeout`` and its connection closed. As many idle connections as the limit (the
probe's attack) leave the gateway serving everyone else."""

from __future__ import annotations

import json
import socket
from pathlib import Path
from urllib.parse import urlparse

import httpx
import pytest

from backend.settings import Settings

IN_FLIGHT = 4


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    return Settings(data_dir=tmp_path / "data", max_in_flight=IN_FLIGHT, body_timeout_s=1.0)


def _read_response(sock: socket.socket) -> bytes:
    sock.settimeout(30)
    out = b""
    while chunk := sock.recv(65536):  # until the server closes the connection
        out += chunk
    return out


def test_slow_bodies_neither_hold_slots_nor_stay_open(gateway: str) -> None:
    url = urlparse(gateway)
    socks = []
    for _ in range(IN_FLIGHT):
        s = socket.create_connection((url.hostname, url.port))
        s.sendall(b"POST /api/auth/nonce HTTP/1.1\r\nHost: x\r\nContent-Type: application/json"
                  b"\r\nContent-Length: 1000\r\n\r\n{")
        socks.append(s)
    try:
        for _ in range(3):  # every slot's connection is waiting on its body meanwhile
            assert httpx.get(f"{gateway}/api/health", timeout=10).status_code == 200
        for s in socks:
            head, _, body = _read_response(s).partition(b"\r\n\r\n")
            assert head.startswith(b"HTTP/1.1 408"), head
            assert json.loads(body)["detail"]["rule"] == "body_timeout"
    finally:
        for s in socks:
            s.close()
    assert httpx.post(f"{gateway}/api/auth/nonce", json={}, timeout=10).status_code != 408
