"""The installed package version, shown in OpenAPI and /api/health."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    VERSION = version("drlaas")
except PackageNotFoundError:  # running from a source tree that is not installed
    VERSION = "0.0.0+source"
