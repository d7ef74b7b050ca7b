"""Browser security headers on every kind of gateway answer: the UI's pages and scripts, API
JSON, errors raised by the layers in front of the routes, and the API docs (their own policy:
Swagger UI's pinned CDN files and its inline starter script by hash). The UI itself runs under
this policy in every browser test (``tests/frontend/fake_api.py``), which fails on any script,
style or frame the policy blocks."""

from __future__ import annotations

import base64
import hashlib

import pytest
from fastapi.testclient import TestClient

from backend.api.docs_page import SWAGGER_CSS_SRI, SWAGGER_JS_SRI, SWAGGER_UI_VERSION
from backend.api.security_headers import CONTENT_SECURITY_POLICY

COMMON = {
    "x-content-type-options": "nosniff",
    "referrer-policy": "no-referrer",
    "x-frame-options": "DENY",
}


def _common(r) -> None:
    for name, value in COMMON.items():
        assert r.headers.get(name) == value, (r.request.url, name, dict(r.headers))


@pytest.mark.parametrize("path", ["/", "/models", "/js/app.js", "/style.css", "/api/health",
                                  "/api/models", "/api/no-such-route"])
def test_pages_api_and_errors_carry_the_policy(client: TestClient, path: str) -> None:
    r = client.get(path)
    _common(r)
    policy = r.headers["content-security-policy"]
    assert policy == CONTENT_SECURITY_POLICY
    directives = dict(d.split(" ", 1) for d in policy.split("; "))
    assert directives["script-src"] == "'self'"  # no inline or foreign script
    assert directives["frame-ancestors"] == "'none'"  # no other site frames the UI
    assert directives["object-src"] == "'none'"


def test_answers_of_the_layers_in_front_of_the_routes_carry_them(client: TestClient) -> None:
    deep = b"[" * 10_000 + b"]" * 10_000
    r = client.post("/api/auth/nonce", content=deep, headers={"Content-Type": "application/json"})
    assert r.status_code == 422 and r.json()["detail"]["rule"] == "json_too_deep"
    _common(r)
    assert "content-security-policy" in r.headers


def test_the_api_docs_have_their_own_policy_and_pinned_files(client: TestClient) -> None:
    """Swagger UI's page: its files pinned to one release with integrity digests, its inline
    starter script allowed by hash only, no framing (it had no policy and loaded whatever
    swagger-ui-dist@5 the CDN served, on the origin that holds the UI's token)."""
    r = client.get("/api/docs")
    assert r.status_code == 200 and "swagger" in r.text.lower()
    _common(r)
    policy = dict(d.split(" ", 1) for d in r.headers["content-security-policy"].split("; "))
    assert policy["frame-ancestors"] == "'none'" and policy["default-src"] == "'none'"
    assert "unsafe" not in policy["script-src"]  # no inline script but the one hashed, no eval
    inline = r.text.split("<script>", 1)[1].split("</script>", 1)[0]
    digest = base64.b64encode(hashlib.sha256(inline.encode()).digest()).decode()
    assert f"'sha256-{digest}'" in policy["script-src"]
    assert f"swagger-ui-dist@{SWAGGER_UI_VERSION}/" in r.text and "@5/" not in r.text
    assert f'integrity="{SWAGGER_JS_SRI}"' in r.text and f'integrity="{SWAGGER_CSS_SRI}"' in r.text


def test_an_unexpected_error_carries_them_too(app) -> None:
    """Starlette answers an unhandled exception outside every middleware, SecurityHeaders
    included: the 500 sets the headers itself."""

    @app.get("/api/test-only-boom")
    def boom() -> None:
        raise RuntimeError("a bug")

    with TestClient(app, raise_server_exceptions=False) as c:
        r = c.get("/api/test-only-boom")
    assert r.status_code == 500 and r.json()["detail"]["rule"] == "internal_error"
    _common(r)
    assert r.headers["content-security-policy"] == CONTENT_SECURITY_POLICY
