"""Demo sign-in for the web UI: only demo users, only where the gateway holds their keys, only
for clients on this machine."""

import pytest
from fastapi.testclient import TestClient

LOCAL = {"client": ("127.0.0.1", 50000), "base_url": "http://127.0.0.1:8000"}


def test_demo_users_get_tokens_and_strangers_do_not(app):
    with TestClient(app, **LOCAL) as client:
        users = client.get("/api/auth/demo-users").json()
        assert users["count"] == len(users["data"]) > 2
        alice = users["data"][1]
        r = client.post("/api/auth/demo-token", json=alice)
        assert r.status_code == 200
        token = r.json()["access_token"]
        me = client.get("/api/auth/me", headers={"Authorization": f"Bearer {token}"}).json()
        assert me["address"] == alice["address"]
        other = users["data"][2]["address"]
        r = client.post("/api/auth/demo-token", json={"name": alice["name"], "address": other})
        assert r.status_code == 403 and r.json()["detail"]["rule"] == "not_a_demo_user"


def test_demo_users_are_not_served_beyond_this_machine(app):
    """A demo token lets the gateway sign as that user (the consortium admin among them)."""
    with TestClient(app, **LOCAL) as local:
        admin = local.get("/api/auth/demo-users").json()["data"][0]
    with TestClient(app, client=("10.0.0.7", 50000)) as remote:
        for r in (
            remote.get("/api/auth/demo-users"),
            remote.post("/api/auth/demo-token", json=admin),
        ):
            assert r.status_code == 404 and r.json()["detail"]["rule"] == "demo_not_local"


@pytest.mark.parametrize(
    "headers",
    [
        {"Host": "attacker.example:8000"},  # DNS rebinding: the page's own name, our address
        {"Host": "127.0.0.1.attacker.example"},
        {"Origin": "https://attacker.example"},  # a page of another site posting here
        {"Origin": "null"},  # a sandboxed frame or a file:// page
    ],
)
def test_a_web_page_on_this_machine_gets_no_demo_keys(app, headers):
    """A browser on this machine is a loopback client for every site it visits: after DNS
    rebinding a page of attacker.example reaches the gateway with its own Host; the demo
    keys (the consortium admin's among them) must not be handed to it."""
    with TestClient(app, **LOCAL) as local:
        admin = local.get("/api/auth/demo-users").json()["data"][0]
        assert local.post("/api/auth/demo-token", json=admin).status_code == 200
        for r in (
            local.get("/api/auth/demo-users", headers=headers),
            local.post("/api/auth/demo-token", json=admin, headers=headers),
        ):
            assert r.status_code == 404 and r.json()["detail"]["rule"] == "demo_not_local", r.text
        assert local.get("/api/local/services").status_code == 200
        r = local.get("/api/local/services", headers=headers)
        assert r.status_code == 404 and r.json()["detail"]["rule"] == "not_local", r.text
        # this machine's own page (the UI at localhost) still gets them
        own = {"Host": "localhost:8000", "Origin": "http://localhost:8000"}
        assert local.post("/api/auth/demo-token", json=admin, headers=own).status_code == 200
        v6 = {"Host": "[::1]:8000"}
        assert local.get("/api/auth/demo-users", headers=v6).status_code == 200
