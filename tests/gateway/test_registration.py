"""Worker registration through the gateway (issue 8): at most four domains; with approval on
(a consortium chain) a new worker is pending until an admin approves it; the worker itself or
an admin removes it."""

from __future__ import annotations

from fastapi.testclient import TestClient

from backend.services.chain import ChainService

from .conftest import Login, P, addr

CAPS = {"cpu_cores": 4, "ram_gb": 8, "gpu_series": 0}


def test_development_chain_registers_workers_active(client: TestClient, login: Login) -> None:
    r = client.post(
        f"{P}/users/workers", json={"domains": [0, 1, 2, 3]} | CAPS, headers=login("user1")
    )
    assert r.status_code == 201 and r.json()["status"] == "active", r.text
    r = client.post(
        f"{P}/users/workers", json={"domains": [0, 1, 2, 3, 4]} | CAPS, headers=login("user2")
    )
    assert r.status_code == 422 and "domains" in r.text


def test_approval_and_removal(client: TestClient, login: Login, service: ChainService) -> None:
    umc = service.platform.umc
    umc.set_approval_required(service.platform.admin, True)
    r = client.post(f"{P}/users/workers", json={"domains": [0]} | CAPS, headers=login("user3"))
    assert r.status_code == 201 and r.json()["status"] == "pending", r.text
    me = addr(service, "user3")
    assert umc.pool(0) == []
    pending = client.get(f"{P}/workers", params={"status": "pending"}).json()["data"]
    assert [w["address"] for w in pending] == [me]

    r = client.post(f"{P}/users/workers/{me}/approval", headers=login("user4"))
    assert r.status_code == 403 and "not_admin" in r.json()["detail"]["rule"], r.text
    r = client.post(f"{P}/users/workers/{me}/approval", headers=login("admin"))
    assert r.status_code == 200 and r.json()["status"] == "active", r.text
    assert umc.pool(0) == [me]

    r = client.delete(f"{P}/users/workers/{me}", headers=login("user4"))
    assert r.status_code == 403 and "not_self_or_admin" in r.json()["detail"]["rule"], r.text
    r = client.delete(f"{P}/users/workers/{me}", headers=login("user3"))
    assert r.status_code == 200 and r.json()["status"] == "removed", r.text
    assert umc.pool(0) == []
    assert client.get(f"{P}/workers/{me}").json()["status"] == "removed"


def test_an_approval_answers_the_status_the_chain_holds(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """A worker that went idle, changed its capabilities (back to pending) and is approved
    again is Idle on chain: the answer says so, as the worker's page does."""
    umc = service.platform.umc
    umc.set_approval_required(service.platform.admin, True)
    r = client.post(f"{P}/users/workers", json={"domains": [0]} | CAPS, headers=login("user5"))
    me = addr(service, "user5")
    assert client.post(f"{P}/users/workers/{me}/approval", headers=login("admin")).json()[
        "status"] == "active"
    service.send(me, umc, "updateStatus", 2)  # idle, with its own key (as the daemon does)
    r = client.post(f"{P}/users/workers", json={"domains": [0]} | CAPS | {"cpu_cores": 8},
                    headers=login("user5"))
    assert r.json()["status"] == "pending", r.text  # updated: sent back for approval
    r = client.post(f"{P}/users/workers/{me}/approval", headers=login("admin"))
    assert r.status_code == 200 and r.json()["status"] == "idle", r.text
    assert client.get(f"{P}/workers/{me}").json()["status"] == "idle"


def test_capabilities_are_integers_not_booleans_or_floats(client: TestClient, login: Login) -> None:
    """JSON ``true`` is not one CPU core, nor ``2.5`` a count of anything."""
    for bad in ({"cpu_cores": True}, {"cpu_cores": 2.5}, {"ram_gb": False}, {"gpu_series": 1.5}):
        body = {"domains": [0], "cpu_cores": 4, "ram_gb": 8} | bad
        r = client.post(f"{P}/users/workers", json=body, headers=login("user7"))
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", *bad], r.text


def test_requesters_wait_for_approval_on_a_consortium_chain(
    client: TestClient, login: Login, service: ChainService
) -> None:
    """A second identity of a worker (the sybil requester of docs/chain.md) cannot post
    tasks until an admin approves it; the task route says why; removal is for good."""
    from .conftest import task_body

    umc = service.platform.umc
    umc.set_approval_required(service.platform.admin, True)
    me = addr(service, "user5")
    r = client.post(f"{P}/users/requesters", headers=login("user5"))
    assert r.status_code == 201 and r.json()["status"] == "pending", r.text
    r = client.post(f"{P}/tasks", json=task_body(num_workers=1), headers=login("user5"))
    assert r.status_code == 403 and r.json()["detail"]["rule"] == "requester_pending", r.text
    assert "approval" in r.json()["detail"]["msg"]

    r = client.post(f"{P}/users/requesters/{me}/approval", headers=login("user6"))
    assert r.status_code == 403 and "not_admin" in r.json()["detail"]["rule"], r.text
    r = client.post(f"{P}/users/requesters/{me}/approval", headers=login("admin"))
    assert r.status_code == 200 and r.json()["status"] == "active", r.text
    assert umc.call("isRequester", me)
    r = client.post(f"{P}/users/requesters/{me}/approval", headers=login("admin"))
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "users_requester_not_pending"

    r = client.delete(f"{P}/users/requesters/{me}", headers=login("user6"))
    assert r.status_code == 403 and "not_self_or_admin" in r.json()["detail"]["rule"], r.text
    r = client.delete(f"{P}/users/requesters/{me}", headers=login("admin"))
    assert r.status_code == 200 and r.json()["status"] == "removed", r.text
    assert not umc.call("isRequester", me)
    r = client.post(f"{P}/users/requesters", headers=login("user5"))
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "users_already_registered"
    r = client.delete(f"{P}/users/requesters/{me}", headers=login("admin"))
    assert r.status_code == 409, r.text
    assert r.json()["detail"]["rule"] == "users_requester_not_registered"
