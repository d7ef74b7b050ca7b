"""FastAPI gateway: ``create_app(settings)`` builds it (routers under ``/api``).

Imported lazily so that ``backend.api.errors`` can be used by services without pulling in the
routers (and without an import cycle through ``backend.auth``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from .main import API_PREFIX, create_app

__all__ = ["API_PREFIX", "create_app"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from . import main

        return getattr(main, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
