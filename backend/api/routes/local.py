"""``GET /api/local/services``: where this gateway's embedded broker and content store live, for
a worker daemon started on the same machine with only ``--gateway``.

The embedded broker (a SQLite file) and store (a directory) are reachable only through the file
system, so such a worker must open the gateway's files. Answered in development mode to
loopback clients only (404 ``not_local`` otherwise): a real deployment gives its workers
``DRLAAS_BROKER`` / ``DRLAAS_IPFS`` URLs, and paths are nobody else's business.
"""

from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

from backend.api.deps import SettingsDep, is_loopback
from backend.api.errors import RuleError, rule_responses

router = APIRouter(prefix="/local", tags=["health"])


class LocalServicesPublic(BaseModel):
    data_dir: str = Field(description="the gateway's data directory (absolute)")
    broker_embedded: bool = Field(description="the broker is the SQLite file in data_dir")
    ipfs_dir: str | None = Field(description="directory of the embedded content store, if any")


@router.get("/services", response_model=LocalServicesPublic, responses=rule_responses(404))
def local_services(settings: SettingsDep, request: Request) -> LocalServicesPublic:
    """The gateway's embedded service locations (same machine, development mode only)."""
    if settings.mode != "development" or not is_loopback(request):
        raise RuleError(
            404, "not_local", "embedded service locations are given to this machine only"
        )
    ipfs = settings.ipfs_service
    return LocalServicesPublic(
        data_dir=str(settings.data_dir),
        broker_embedded=settings.broker_service.embedded,
        ipfs_dir=ipfs.url if ipfs.embedded else None,
    )
