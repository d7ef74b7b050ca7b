"""Indexer fixtures: the gateway tests' embedded platform (one per session, rolled back after
each test)."""

from tests.gateway.conftest import chain_service, service

__all__ = ["chain_service", "service"]
