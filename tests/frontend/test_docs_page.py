"""/api/docs in Chromium: Swagger UI runs under the page's own policy with the pinned files, and
files other than the pinned release's bytes are refused (backend/api/docs_page.py). The CDN is
replaced by the npm package of the same release (tests/swagger-ui, installed by make setup)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.responses import HTMLResponse

from backend.api.docs_page import SWAGGER_UI_VERSION, docs_page
from backend.api.security_headers import SecurityHeaders

from .conftest import LiveServer

PACKAGE = Path(__file__).resolve().parents[1] / "swagger-ui" / "node_modules" / "swagger-ui-dist"


def _app() -> FastAPI:
    app = FastAPI(title="docs probe", docs_url=None, redoc_url=None)

    @app.get("/api/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        return docs_page("/openapi.json", "docs probe")

    @app.get("/api/ping")
    def ping() -> dict[str, bool]:
        return {"ok": True}

    app.add_middleware(SecurityHeaders)
    return app


def _open(browser: Any, url: str, tamper: bool) -> tuple[Any, Any, list[str]]:
    ctx = browser.new_context()
    page = ctx.new_page()
    console: list[str] = []
    page.on("console", lambda m: console.append(m.text))
    page.on("pageerror", lambda e: console.append(f"pageerror: {e}"))

    def serve(route: Any) -> None:
        name = route.request.url.rsplit("/", 1)[1]
        body = (PACKAGE / name).read_bytes() + (b"\n/* changed */" if tamper else b"")
        kind = "text/css" if name.endswith(".css") else "application/javascript"
        route.fulfill(status=200, body=body,
                      headers={"content-type": kind, "access-control-allow-origin": "*"})

    page.route("https://cdn.jsdelivr.net/**", serve)
    page.goto(url + "/api/docs")
    return ctx, page, console


@pytest.mark.skipif(not PACKAGE.is_dir(), reason="tests/swagger-ui not installed (make setup)")
def test_swagger_ui_runs_under_its_policy_and_only_with_the_pinned_files(browser: Any) -> None:
    import json

    version = json.loads((PACKAGE / "package.json").read_text())["version"]
    assert version == SWAGGER_UI_VERSION
    with LiveServer(_app()) as server:
        ctx, page, console = _open(browser, server.url, tamper=False)
        page.wait_for_selector(".swagger-ui .info .title", timeout=15000)
        assert "docs probe" in page.inner_text(".swagger-ui .info .title")
        page.wait_for_selector('.opblock-summary-path[data-path="/api/ping"]', timeout=15000)
        assert console == [], console  # no policy violation, no script error
        ctx.close()
        ctx, page, console = _open(browser, server.url, tamper=True)
        page.wait_for_timeout(1500)
        assert page.locator(".swagger-ui .info").count() == 0
        assert any("integrity" in line for line in console), console
        ctx.close()
