"""Chain indexer: contract events -> SQL tables (see :mod:`backend.indexer.indexer`)."""

from __future__ import annotations

from .indexer import Indexer, IndexerThread, OfferHook

__all__ = ["Indexer", "IndexerThread", "OfferHook"]
