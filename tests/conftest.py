"""Test-session hooks shared by every test directory."""

from __future__ import annotations

from typing import Any


def pytest_collection_modifyitems(items: list[Any]) -> None:
    """The end-to-end files of tests/platform first (stable otherwise): ``--dist loadfile``
    hands files to the test processes in collection order, and these take one to two minutes
    each, so one of them left for the end ran alone while the other process sat idle."""
    items.sort(key=lambda item: not item.nodeid.startswith("tests/platform/"))
