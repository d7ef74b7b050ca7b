"""Demo sign-in for the web UI: only demo users, only where the gateway holds their keys."""


def test_demo_users_get_tokens_and_strangers_do_not(client):
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
