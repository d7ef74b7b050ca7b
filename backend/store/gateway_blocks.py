"""A read-only content store over a DRLaaS gateway's ``GET /api/blocks/{cid}``.

Files are rebuilt from blocks by :class:`~backend.store.base.ContentStore` itself, which checks
every block against its CID: the gateway is trusted with nothing. Used by clients that cannot
reach the platform's store directly (``drlaas model pull``, ``drlaas task pull``).
"""

from __future__ import annotations

from typing import BinaryIO

import httpx

from ..httpbounds import MAX_BYTES, bounded_client
from .base import ContentStore
from .cid import CID
from .errors import ContentTooLarge, NotFound, StoreError, StoreUnavailable


class GatewayBlocks(ContentStore):
    """``GatewayBlocks("http://gateway:8000")``: reads only; writes and pins raise. Its own
    client bounds every answer (:mod:`backend.httpbounds`: a block within ``2 x timeout`` of
    its headers, 64 KiB of an error body); a ``client`` given is used as it is."""

    def __init__(
        self,
        url: str,
        *,
        timeout: float = 60.0,
        max_size: int | None = None,
        client: httpx.Client | None = None,
    ) -> None:
        super().__init__(**({"max_size": max_size} if max_size else {}))
        self.url = url.rstrip("/")
        self._client = client or bounded_client(base_url=self.url, timeout=timeout)

    def __repr__(self) -> str:
        return f"GatewayBlocks({self.url!r})"

    def close(self) -> None:
        self._client.close()

    def _read_block(self, cid: CID, max_bytes: int) -> bytes:
        try:
            # the canonical v1 text: the only form the route accepts (a dag-pb link may be v0)
            with self._client.stream(  # the size is bounded below, by max_bytes
                "GET", f"/api/blocks/{cid.v1()}", extensions={MAX_BYTES: None}
            ) as r:
                if r.status_code == 404:
                    raise NotFound(str(cid), f"{self.url} does not hold it")
                if not r.is_success:
                    r.read()
                    raise StoreUnavailable(
                        self.url, f"GET block {cid} -> {r.status_code}: {r.text[:500]}"
                    )
                out = bytearray()
                for chunk in r.iter_bytes():
                    out += chunk
                    if len(out) > max_bytes:
                        raise ContentTooLarge(None, max_bytes, f"block {cid}")
                return bytes(out)
        except httpx.HTTPError as exc:
            raise StoreUnavailable(self.url, f"cannot fetch block {cid}: {exc}") from exc

    def has(self, cid: str | CID) -> bool:
        try:
            self._read_block(CID.parse(cid), 4 * 2**20)
        except NotFound:
            return False
        return True

    def ping(self) -> dict[str, str]:
        try:
            r = self._client.get("/api/health")
        except httpx.HTTPError as exc:
            raise StoreUnavailable(self.url, str(exc)) from exc
        return {"backend": "gateway-blocks", "version": str(r.json().get("version", "?"))}

    def _read_only(self, what: str) -> StoreError:
        return StoreError(f"{self!r} is read-only: cannot {what}")

    def _add_stream(self, source: bytes | BinaryIO, *, pin: bool) -> str:
        raise self._read_only("add content")

    def pin(self, cid: str | CID) -> None:
        raise self._read_only("pin")

    def unpin(self, cid: str | CID) -> None:
        raise self._read_only("unpin")

    def pins(self) -> list[str]:
        raise self._read_only("list pins")
