"""Content store backed by an IPFS node's RPC API (Kubo ``/api/v0``, also served by js-ipfs).

A thin client over httpx rather than ``ipfshttpclient``: that library's last release (0.7.0,
2021) refuses every daemon newer than 0.8 in ``connect()``, its ``add_bytes`` rejects the
``cid_version`` option, it emits urllib3 deprecation warnings, and it cannot bound the size of a
download while streaming it. The RPC API is plain HTTP POST; the five calls needed are here.

Trust model: the node is not trusted. Uploads compute the CID locally and compare it with the
node's answer; downloads fetch block by block (``block/get``) and verify each block against its
CID, with the size bound enforced while bytes arrive.
"""

from __future__ import annotations

import copy
import json
import random
import re
import time
from collections.abc import Callable
from typing import Any, BinaryIO, TypeVar

import httpx

from ..httpbounds import DEADLINE_S, MAX_BYTES, bounded_client
from .base import DEFAULT_MAX_SIZE, ContentStore
from .cid import CID, cid_key
from .dag import ADD_PARAMS, build_dag, iter_chunks
from .errors import (
    CIDMismatch,
    ContentTooLarge,
    FindTimeout,
    NotFound,
    StoreError,
    StoreUnavailable,
)

T = TypeVar("T")

_NOT_FOUND = re.compile(
    r"not found|could not find|no link named|not pinned|block was not found",
    re.IGNORECASE,
)
"""Node error messages that mean "this content is not available" (Kubo and js-ipfs wording)."""

_TIMED_OUT = re.compile(r"request timed out|context deadline exceeded", re.IGNORECASE)
"""Node error messages that mean it gave up looking after ``find_timeout`` (js-ipfs, Kubo):
:class:`FindTimeout`, not a plain :class:`NotFound` (the provider may be offline a while)."""

_TRANSIENT = (httpx.TransportError,)
"""Failures of the connection (refused, reset, timed out, broken HTTP): :class:`StoreUnavailable`,
retried. Any other ``httpx.HTTPError`` (a body that does not decode as its Content-Encoding
says, say) is an answer the node got wrong: :class:`StoreError`, not retried."""

DEADLINE_FACTOR = 4
"""A block read, all its bytes, may take at most this many ``timeout``s by default: the
timeout bounds each read only, and a node sending a byte per ``timeout - 1`` s would otherwise
hold a worker for days."""

MAX_ANSWER_BYTES = 32 * 2**20
"""Largest JSON answer read from the node (``pin/ls`` of a big node is the largest); error
bodies are read up to 64 KiB only (:mod:`backend.httpbounds`)."""
_OWN_BOUNDS = {MAX_BYTES: None, DEADLINE_S: None}
"""``block/get``: :meth:`IpfsRpcStore._read_block` bounds a block's size and time itself."""


def normalize_api_url(url: str) -> str:
    """``http://h:p``, ``http://h:p/api/v0`` or a multiaddr ``/ip4/h/tcp/p[/http]`` ->
    ``http://h:p/api/v0``."""
    text = url.strip()
    m = re.fullmatch(r"/(ip4|ip6|dns|dns4|dns6)/([^/]+)/tcp/(\d+)(/https?)?/?", text)
    if m:
        host = f"[{m.group(2)}]" if m.group(1) == "ip6" else m.group(2)
        scheme = "https" if m.group(4) == "/https" else "http"
        text = f"{scheme}://{host}:{m.group(3)}"
    if not re.match(r"https?://", text):
        raise ValueError(
            f"IPFS RPC API URL must be http(s):// or a /ip4/.../tcp/... multiaddr, got {url!r}"
        )
    text = text.rstrip("/")
    if not text.endswith("/api/v0"):
        text += "/api/v0"
    return text


class IpfsRpcStore(ContentStore):
    """Content store talking to an IPFS node over its RPC API.

    ``timeout``: seconds for connecting/reading one HTTP response. ``deadline``: seconds one
    block read may take in all (default ``DEADLINE_FACTOR * timeout``; checked as bytes arrive,
    so a read ends within ``deadline + timeout``). ``find_timeout``: how long the
    node may search for a block before the call counts as :class:`FindTimeout` (a
    :class:`NotFound` callers may retry). ``retries``: extra
    attempts, with capped exponential backoff and jitter, for transient failures only
    (connection refused, timeouts, 502/503/504); after them :class:`StoreUnavailable`.
    """

    def __init__(
        self,
        url: str,
        *,
        max_size: int = DEFAULT_MAX_SIZE,
        timeout: float = 30.0,
        find_timeout: float = 10.0,
        retries: int = 2,
        backoff: float = 0.25,
        transport: httpx.BaseTransport | None = None,
        deadline: float | None = None,
    ) -> None:
        super().__init__(max_size=max_size)
        self.url = normalize_api_url(url)
        self.deadline = deadline if deadline is not None else DEADLINE_FACTOR * timeout
        self.find_timeout = find_timeout
        self.retries = max(0, retries)
        self.backoff = backoff
        self._client = bounded_client(  # every answer within max/deadline (R4)
            base_url=self.url,
            timeout=httpx.Timeout(timeout, connect=min(timeout, 5.0)),
            transport=transport,
            max_bytes=MAX_ANSWER_BYTES,
            deadline_s=self.deadline,
        )

    def __repr__(self) -> str:
        return f"IpfsRpcStore({self.url!r})"

    def close(self) -> None:
        self._client.close()

    def with_find_timeout(self, seconds: float) -> IpfsRpcStore:
        """The same node and HTTP client, with the node told to give up looking after at most
        ``seconds`` (never longer than this store's own ``find_timeout``). It shares the
        client: close the original, not the copy."""
        if not seconds > 0:
            raise ValueError(f"find timeout must be > 0 s, got {seconds}")
        quick = copy.copy(self)
        quick.find_timeout = min(self.find_timeout, seconds)
        return quick

    # -- HTTP plumbing -----------------------------------------------------------------------------
    def _retrying(self, what: str, call: Callable[[], T]) -> T:
        delay = self.backoff
        for attempt in range(self.retries + 1):
            try:
                return call()
            except StoreUnavailable:
                if attempt == self.retries:
                    raise
            time.sleep(min(delay, 5.0) * (0.5 + random.random()))
            delay *= 2
        raise AssertionError("unreachable")  # pragma: no cover

    def _find_timeout(self) -> str:
        return f"{self.find_timeout:g}s"

    def _unavailable(self, endpoint: str, reason: str) -> StoreUnavailable:
        retry_after = max(1.0, self.backoff * 8)
        return StoreUnavailable(self.url, f"{endpoint}: {reason}", retry_after=retry_after)

    def _http_error(self, endpoint: str, exc: httpx.HTTPError) -> StoreError:
        """The store error of an httpx failure: transport ones are transient."""
        if isinstance(exc, _TRANSIENT):
            return self._unavailable(endpoint, f"{type(exc).__name__}: {exc}")
        return StoreError(f"IPFS node {self.url} answered {endpoint} wrongly: "
                          f"{type(exc).__name__}: {exc}")

    def _check(self, endpoint: str, response: httpx.Response, arg: str = "") -> None:
        """Map a non-200 answer to a typed error."""
        if response.status_code == 200:
            return
        if not response.is_stream_consumed:
            response.read()  # its first 64 KiB only (bounded_client)
        try:
            message = str(json.loads(response.content).get("Message", ""))
        except (ValueError, AttributeError):
            message = response.text[:200]
        if response.status_code in (502, 503, 504):
            raise self._unavailable(endpoint, f"HTTP {response.status_code} {message}")
        if _TIMED_OUT.search(message):
            raise FindTimeout(arg or endpoint, f"node says: {message}", after=self.find_timeout)
        if _NOT_FOUND.search(message):
            raise NotFound(arg or endpoint, f"node says: {message}")
        raise StoreError(
            f"IPFS node rejected {endpoint} {arg}: HTTP {response.status_code} {message}"
        )

    def _post(self, endpoint: str, params: dict[str, Any], **kw: Any) -> httpx.Response:
        try:
            response = self._client.post(endpoint, params=params, **kw)
            self._check(endpoint, response, str(params.get("arg", "")))
        except httpx.HTTPError as e:
            raise self._http_error(endpoint, e) from e
        return response

    def _json(self, endpoint: str, params: dict[str, Any]) -> dict[str, Any]:
        response = self._retrying(endpoint, lambda: self._post(endpoint, params))
        try:
            answer = json.loads(response.content)
        except (ValueError, RecursionError):
            answer = None
        if not isinstance(answer, dict):
            raise StoreError(f"IPFS node {self.url} answered {endpoint} with no JSON object: "
                             f"{response.content[:200]!r}")
        return answer

    # -- writing -----------------------------------------------------------------------------------
    def _add_stream(self, source: bytes | BinaryIO, *, pin: bool) -> str:
        start = 0 if isinstance(source, bytes) else source.tell()
        expected, size = build_dag(iter_chunks(source), max_size=self.max_size)
        params = dict(ADD_PARAMS, pin="true" if pin else "false", quieter="true")

        def upload() -> httpx.Response:
            if not isinstance(source, bytes):
                source.seek(start)
            files = {"file": ("blob", source, "application/octet-stream")}
            return self._post("add", params, files=files)

        response = self._retrying("add", upload)
        answer: dict[str, Any] = {}
        for line in response.text.splitlines():
            try:
                entry = json.loads(line) if line.strip() else None
            except (ValueError, RecursionError):
                entry = None
            if isinstance(entry, dict) and isinstance(entry.get("Hash"), str):
                answer = entry
        if "Hash" not in answer:
            raise StoreError(f"IPFS node gave no CID for add: {response.text[:200]!r}")
        got = cid_key(answer["Hash"])
        if got != str(expected):
            raise CIDMismatch(str(expected), got, f"node {self.url} answered add of {size} bytes")
        return got

    # -- reading -----------------------------------------------------------------------------------
    def _read_block(self, cid: CID, max_bytes: int) -> bytes:
        params = {"arg": str(cid), "timeout": self._find_timeout()}

        def fetch() -> bytes:
            give_up = time.monotonic() + self.deadline
            try:
                with self._client.stream(  # size and time are bounded below
                    "POST", "block/get", params=params, extensions=_OWN_BOUNDS
                ) as response:
                    self._check("block/get", response, str(cid))
                    length = response.headers.get("content-length")
                    if length is not None and length.isdigit() and int(length) > max_bytes:
                        raise ContentTooLarge(int(length), max_bytes, f"block {cid}")
                    buf = bytearray()
                    for part in response.iter_bytes():
                        buf += part
                        if len(buf) > max_bytes:
                            raise ContentTooLarge(None, max_bytes, f"block {cid}")
                        if time.monotonic() > give_up:
                            raise self._unavailable(
                                "block/get",
                                f"block {cid} not received within {self.deadline:g} s "
                                f"({len(buf)} bytes so far)",
                            )
                    return bytes(buf)
            except httpx.HTTPError as e:
                raise self._http_error("block/get", e) from e

        return self._retrying("block/get", fetch)

    def has(self, cid: str | CID) -> bool:
        """Whether the node can produce the root block within ``find_timeout``."""
        try:
            self._json("block/stat", {"arg": str(CID.parse(cid)), "timeout": self._find_timeout()})
        except NotFound:
            return False
        return True

    # -- pins --------------------------------------------------------------------------------------
    def pin(self, cid: str | CID) -> None:
        self._json("pin/add", {"arg": str(CID.parse(cid)), "timeout": self._find_timeout()})

    def unpin(self, cid: str | CID) -> None:
        self._json("pin/rm", {"arg": str(CID.parse(cid))})

    def pins(self) -> list[str]:
        answer = self._json("pin/ls", {"type": "recursive"})
        keys = answer.get("Keys") or {}
        if not isinstance(keys, dict):
            raise StoreError(f"IPFS node {self.url} answered pin/ls without a Keys object")
        return sorted(cid_key(key) for key in keys)

    def ping(self) -> dict[str, str]:
        answer = self._json("version", {})
        return {"backend": "ipfs-rpc", "url": self.url, "version": str(answer.get("Version", "?"))}
