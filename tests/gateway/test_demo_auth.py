"""Demo sign-in for the web UI: only demo users, only where the gateway holds their keys, only
for clients on this machine."""

from fastapi.testclient import TestClient


def test_demo_users_get_tokens_and_strangers_do_not(app):
    with TestClient(app, client=("127.0.0.1", 50000)) as client:
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
    with TestClient(app, client=("127.0.0.1", 50000)) as local:
        admin = local.get("/api/auth/demo-users").json()["data"][0]
    with TestClient(app, client=("10.0.0.7", 50000)) as remote:
        for r in (
            remote.get("/api/auth/demo-users"),
            remote.post("/api/auth/demo-token", json=admin),
        ):
            assert r.status_code == 404 and r.json()["detail"]["rule"] == "demo_not_local"
