"""Content store (Deliverable 2 of the platform): one interface, an embedded and an IPFS backend.

``make_store(spec)`` picks the backend from the ``DRLAAS_IPFS`` setting's forms:

* ``embedded:<dir>``, ``file://<dir>`` or a plain directory path -> :class:`EmbeddedStore`
* ``embedded`` -> :class:`EmbeddedStore` in ``default_dir`` (the settings pass ``<data_dir>/ipfs``)
* ``http(s)://host:port`` or a multiaddr ``/ip4/host/tcp/port`` -> :class:`IpfsRpcStore`
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from .base import DEFAULT_MAX_SIZE, ContentStore
from .cid import CID
from .dag import ADD_PARAMS, CHUNK_SIZE, MAX_LINKS, compute_cid
from .embedded import EmbeddedStore
from .errors import (
    CIDMismatch,
    ContentTooLarge,
    FindTimeout,
    InvalidCID,
    InvalidContent,
    NotFound,
    StoreError,
    StoreUnavailable,
)
from .ipfs_rpc import IpfsRpcStore

__all__ = [
    "ADD_PARAMS",
    "CHUNK_SIZE",
    "CID",
    "CIDMismatch",
    "ContentStore",
    "ContentTooLarge",
    "DEFAULT_MAX_SIZE",
    "EmbeddedStore",
    "FindTimeout",
    "InvalidCID",
    "InvalidContent",
    "IpfsRpcStore",
    "MAX_LINKS",
    "NotFound",
    "StoreError",
    "StoreUnavailable",
    "compute_cid",
    "make_store",
]


def make_store(
    spec: str | os.PathLike[str],
    *,
    default_dir: str | os.PathLike[str] | None = None,
    max_size: int = DEFAULT_MAX_SIZE,
    **options: Any,
) -> ContentStore:
    """Build the store named by ``spec``; ``options`` go to the backend's constructor
    (e.g. ``fsync`` for embedded, ``timeout``/``retries`` for RPC)."""
    if isinstance(spec, os.PathLike):
        return EmbeddedStore(spec, max_size=max_size, **options)
    text = spec.strip()
    if re.match(r"https?://", text) or re.match(r"/(ip4|ip6|dns|dns4|dns6)/", text):
        return IpfsRpcStore(text, max_size=max_size, **options)
    if text == "embedded":
        if default_dir is None:
            raise ValueError("store spec 'embedded' needs default_dir (or use 'embedded:<dir>')")
        return EmbeddedStore(default_dir, max_size=max_size, **options)
    for prefix in ("embedded:", "file://"):
        if text.startswith(prefix):
            text = text[len(prefix) :]
            break
    else:
        if "://" in text:
            raise ValueError(
                f"unsupported content store {spec!r}: use embedded[:dir], a directory path or "
                "an http(s) IPFS RPC API URL"
            )
    if not text:
        raise ValueError(f"content store spec {spec!r} names no directory")
    return EmbeddedStore(Path(text), max_size=max_size, **options)
