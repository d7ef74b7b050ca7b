"""The gateway's redirects never send a client to the host its ``Host`` header named: the
router's trailing-slash redirect and the docs aliases answer with a relative ``Location``."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from backend.api.relative_redirects import relative_location


@pytest.mark.parametrize(
    ("path", "target"),
    [
        ("/api/models/", "/api/models"),
        ("/api/tasks/?limit=2&offset=1", "/api/tasks?limit=2&offset=1"),
        ("/rpc/", "/rpc"),
    ],
)
def test_a_slash_redirect_names_no_host_from_the_request(
    client: TestClient, path: str, target: str
) -> None:
    r = client.get(path, headers={"Host": "evil.example"}, follow_redirects=False)
    assert r.status_code == 307
    assert r.headers["location"] == target
    followed = client.get(path)  # the test client's own host: it still lands on the route
    assert followed.status_code in (200, 405), followed.text
    assert followed.url.path == target.split("?")[0]


def test_the_docs_aliases_still_redirect(client: TestClient) -> None:
    r = client.get("/docs", headers={"Host": "evil.example"}, follow_redirects=False)
    assert r.status_code == 307 and r.headers["location"] == "/api/docs"


def test_only_locations_on_the_request_host_are_rewritten() -> None:
    assert relative_location("http://evil.example/api/x?a=1", "evil.example") == "/api/x?a=1"
    assert relative_location("https://EVIL.example:8000/", "evil.example:8000") == "/"
    assert relative_location("http://evil.example//other.host/x", "evil.example") == "/other.host/x"
    assert relative_location("https://elsewhere.example/x", "evil.example") == (
        "https://elsewhere.example/x"
    )
    assert relative_location("/api/x", "evil.example") == "/api/x"
