"""``mount_frontend`` on the real gateway: UI routes fall back to index.html, API paths keep
their own answers (no browser needed)."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from backend.api.frontend import mount_frontend
from backend.api.main import create_app
from backend.settings import Settings
from tests.frontend.conftest import LiveServer


def test_real_gateway_serves_ui_and_api_side_by_side(tmp_path: Path) -> None:

    app = create_app(Settings(data_dir=tmp_path / "data"))
    mount_frontend(app)
    with LiveServer(app) as server, httpx.Client(base_url=server.url) as c:
        assert '<main id="main">' in c.get("/tasks/3").text  # client route -> index.html
        assert c.get("/api/health").json()["status"] == "ok"  # routes win over the mount
        assert c.get("/api/openapi.json").json()["info"]["title"] == "DRLaaS gateway"
        r = c.get("/api/nope")
        assert r.status_code == 404 and r.json()["detail"]["rule"] == "not_found"
        assert c.post("/api/health").status_code == 405


def test_mount_frontend_names_a_missing_ui(tmp_path: Path) -> None:
    app = create_app(Settings(data_dir=tmp_path / "data"))
    with pytest.raises(FileNotFoundError, match=str(tmp_path / "index.html")):
        mount_frontend(app, tmp_path)
