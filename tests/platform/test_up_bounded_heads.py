"""`drlaas up` serves the gateway with the bounded request head (backend/api/http_limits.py):
the bound lives in the server's protocol, so a gateway started without it buffered a header
of any size whole."""

from __future__ import annotations

import socket
from pathlib import Path

from backend.api.http_limits import MAX_HEAD_BYTES
from drlaas.commands.up import running_platform


def test_the_platform_gateway_refuses_a_request_head_past_the_bound(tmp_path: Path) -> None:
    with running_platform(workers=0, data_dir=tmp_path / "platform") as p:
        port = int(p.url.rsplit(":", 1)[1])
        head = (b"GET /api/health HTTP/1.1\r\nHost: x\r\nX-Filler: "
                + b"a" * (4 * MAX_HEAD_BYTES) + b"\r\n\r\n")
        with socket.create_connection(("127.0.0.1", port), timeout=20) as s:
            try:
                s.sendall(head)
            except (BrokenPipeError, ConnectionResetError):
                pass  # the gateway may close before the whole head is sent
            answer = s.recv(4096)
    assert answer.startswith(b"HTTP/1.1 431"), answer[:200]
