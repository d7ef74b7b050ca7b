"""A bound on a request's head (request line and header fields), which no ASGI app can set.

uvicorn's default parser (httptools) keeps a request's head until it is complete, however long:
one anonymous connection that sent a 200 MB header value grew the gateway by 200 MB, answered
200 at the end (the 2026-12-05 held-out pass), and a few such connections exhaust the memory of
the machine. The app sees a request only once its head is complete, so the bound lives in the
server's protocol: :class:`BoundedHttpToolsProtocol` answers 431 ``headers_too_large`` (in the
gateway's error shape) and closes the connection once a head passes :data:`MAX_HEAD_BYTES`.

Serve with it: ``uvicorn.Config(app, http=BoundedHttpToolsProtocol)``, or
``uvicorn --http backend.api.http_limits:BoundedHttpToolsProtocol``. (uvicorn's h11 protocol
has its own bound, ``h11_max_incomplete_event_size``.)
"""

from __future__ import annotations

import json
from typing import Any

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

from backend.api.security_headers import security_headers

MAX_HEAD_BYTES = 64 * 1024
"""Bytes of one request's head at most (nginx's default is 32 KiB; a signed-in request with
every header a browser sends is under 4 KiB). A head is counted by the reads that carry only
head bytes, so up to one read (256 KiB in asyncio) more may be buffered before the refusal."""


class BoundedHttpToolsProtocol(HttpToolsProtocol):
    """httptools' protocol with :data:`MAX_HEAD_BYTES` per request head."""

    max_head_bytes = MAX_HEAD_BYTES

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._head_bytes = 0  # of the head being read, from reads that held nothing else
        self._in_body = False  # between a head's end and its message's end
        self._heads = self._messages = 0  # heads and messages completed so far

    def on_headers_complete(self) -> None:
        self._heads += 1
        self._head_bytes, self._in_body = 0, True
        super().on_headers_complete()

    def on_message_complete(self) -> None:
        self._messages += 1
        self._in_body = False
        super().on_message_complete()

    def data_received(self, data: bytes) -> None:
        in_head = not self._in_body
        heads, messages = self._heads, self._messages
        super().data_received(data)
        if not in_head or heads != self._heads or messages != self._messages:
            return  # the read held a body or a head's end: not (only) head bytes
        if self.transport.is_closing():
            return
        self._head_bytes += len(data)
        if self._head_bytes > self.max_head_bytes:
            self._refuse()

    def _refuse(self) -> None:
        body = json.dumps({"detail": {
            "rule": "headers_too_large",
            "msg": f"a request's line and header fields are at most {self.max_head_bytes} "
                   "bytes",
        }}).encode()  # fmt: skip
        headers = [
            *self.server_state.default_headers,
            *((k.encode(), v.encode()) for k, v in security_headers().items()),
        ]
        head = [b"HTTP/1.1 431 Request Header Fields Too Large\r\n"]
        head += [name + b": " + value + b"\r\n" for name, value in headers]
        head += [
            b"content-type: application/json\r\n",
            b"content-length: " + str(len(body)).encode() + b"\r\n",
            b"connection: close\r\n\r\n",
        ]
        self.transport.write(b"".join(head) + body)
        self.transport.close()
