"""UMC (Users Manager): registration, status, capabilities, counters, admin roles."""

from __future__ import annotations

from backend.chain.platform import WorkerStatus

from .conftest import DOMAIN
from .helpers import reverts

ASSIGNED, ACCEPTED, COMPLETED, REVIEWED = 1, 2, 4, 8


def test_add_worker_registers_in_each_domain(p, actors) -> None:
    w = actors.workers[0]
    rc = p.umc.add_worker(w, [DOMAIN, 40], 8, 32, 2)
    ev = rc.one("WorkerAdded").args
    assert (ev["worker"], ev["id"], ev["domains"]) == (w, 1, (1 << DOMAIN) | (1 << 40))
    for d in (DOMAIN, 40):
        assert [x["address"] for x in p.umc.get_workers(d)] == [w]
    assert p.umc.get_workers(DOMAIN + 1) == []
    assert p.umc.get_workers(DOMAIN)[0] == {
        "address": w,
        "status": WorkerStatus.ACTIVE,
        "gpu_series": 2,
        "cpu_cores": 8,
        "ram_gb": 32,
        "domains": (1 << DOMAIN) | (1 << 40),
    }
    reverts("UsersAlreadyRegistered", p.umc.add_worker, w, [DOMAIN], 1, 1, 1)
    reverts("UsersBadDomains", p.umc.add_worker, actors.workers[1], [], 1, 1, 1)
    err = reverts(
        "UsersBadDomains", p.umc.transact, "addWorker", 1 << 48, 1, 1, 1, sender=actors.workers[1]
    )
    assert err.args_dict["domains"] == 1 << 48
    assert p.umc.call("domainsOf", w) == (1 << DOMAIN) | (1 << 40)


def test_get_workers_reads_every_page(p, actors, monkeypatch) -> None:
    """getWorkers is paged: get_workers concatenates pages in registration order."""
    ws = actors.workers[:5]
    for i, w in enumerate(ws):
        p.umc.add_worker(w, [DOMAIN], 1 + i, 8, 1)
    monkeypatch.setattr(p.umc, "WORKERS_PAGE", 2)
    assert [x["address"] for x in p.umc.get_workers(DOMAIN)] == ws
    assert [x["cpu_cores"] for x in p.umc.get_workers(DOMAIN)] == [1, 2, 3, 4, 5]
    assert [w[0] for w in p.umc.call("getWorkers", DOMAIN, 3, 10)] == ws[3:]
    assert p.umc.call("getWorkers", DOMAIN, 5, 10) == []
    assert p.umc.call("getWorkers", DOMAIN, 2**256 - 1, 2**256 - 1) == []


def test_add_requester_once(p, actors) -> None:
    r = actors.requester
    assert not p.umc.call("isRequester", r)
    assert p.umc.add_requester(r).one("RequesterAdded").args["requester"] == r
    assert p.umc.call("isRequester", r)
    reverts("UsersAlreadyRegistered", p.umc.add_requester, r)


def test_update_status_and_capabilities(p, actors) -> None:
    w = actors.workers[0]
    p.umc.add_worker(w, [DOMAIN], 8, 32, 2)
    rc = p.umc.update_status(w, WorkerStatus.IDLE)
    assert rc.one("WorkerStatusUpdated").args["status"] == WorkerStatus.IDLE
    assert p.umc.call("getWorker", w)[1] == WorkerStatus.IDLE
    reverts("UsersBadStatus", p.umc.update_status, w, WorkerStatus.NONE)
    reverts("UsersNotWorker", p.umc.update_status, actors.outsider, WorkerStatus.IDLE)
    rc = p.umc.transact("updateCapabilities", 16, 128, 3, sender=w)
    assert rc.one("WorkerCapabilitiesUpdated").args["cpuCores"] == 16
    assert tuple(p.umc.call("getWorker", w))[2:5] == (3, 16, 128)


def test_update_info_counters_and_checks(p, actors) -> None:
    admin, w = actors.admin, actors.workers[0]
    p.umc.add_worker(w, [DOMAIN], 8, 32, 2)
    reverts(
        "UsersNotPlatform", p.umc.transact, "updateInfo", w, DOMAIN, 0, ASSIGNED, 0, sender=admin
    )
    p.umc.transact("setPlatform", admin, True, sender=admin)
    rc = p.umc.transact(
        "updateInfo", w, DOMAIN, 1, ASSIGNED | ACCEPTED | COMPLETED | REVIEWED, 4, sender=admin
    )
    ev = rc.one("WorkerInfoUpdated").args
    assert (
        ev["assigned"],
        ev["accepted"],
        ev["completed"],
        ev["ratingSum"],
        ev["ratingCount"],
    ) == (1, 1, 1, 4, 1)
    assert p.umc.counters(w, DOMAIN, 1)["rating_sum"] == 4
    assert p.umc.counters(w, DOMAIN, 0)["assigned"] == 0  # per task type
    reverts(
        "UsersCountersInconsistent",
        p.umc.transact,
        "updateInfo",
        w,
        DOMAIN,
        0,
        ACCEPTED,
        0,
        sender=admin,
    )
    reverts("UsersBadReview", p.umc.transact, "updateInfo", w, DOMAIN, 0, REVIEWED, 6, sender=admin)
    reverts("UsersBadFlags", p.umc.transact, "updateInfo", w, DOMAIN, 0, 0, 0, sender=admin)
    for bad in (16, 17, 31, 32, 255):  # counters only grow: no flag above 15 (the old WITHDRAWN)
        reverts("UsersBadFlags", p.umc.transact, "updateInfo", w, DOMAIN, 0, bad, 0, sender=admin)
    reverts(
        "UsersBadTaskType", p.umc.transact, "updateInfo", w, DOMAIN, 2, ASSIGNED, 0, sender=admin
    )
    reverts(
        "UsersNotWorker",
        p.umc.transact,
        "updateInfo",
        actors.outsider,
        DOMAIN,
        0,
        ASSIGNED,
        0,
        sender=admin,
    )


def test_admin_set_management(p, actors) -> None:
    admin, other = actors.admin, actors.outsider
    reverts("UsersLastAdmin", p.umc.transact, "setAdmin", admin, False, sender=admin)
    rc = p.umc.transact("setAdmin", other, True, sender=admin)
    assert rc.one("AdminUpdated").args == {"account": other, "isAdmin": True}
    assert p.umc.call("adminCount") == 2
    # one admin of two cannot remove the other: its vote waits for a majority (2 of 2)
    rc = p.umc.transact("setAdmin", admin, False, sender=other)
    vote = rc.one("ChangeVoted").args
    assert (vote["account"], vote["on"], vote["votes"], vote["quorum"]) == (admin, False, 1, 2)
    assert p.umc.call("isAdmin", admin)
    reverts("UsersAlreadyVoted", p.umc.transact, "setAdmin", admin, False, sender=other)
    # an admin may leave alone
    p.umc.transact("setAdmin", admin, False, sender=admin)
    assert not p.umc.call("isAdmin", admin)
    reverts("UsersNotAdmin", p.umc.transact, "setPlatform", admin, True, sender=admin)


def test_candidate_packing_matches_storage(p, actors) -> None:
    w = actors.workers[0]
    p.umc.add_worker(w, [DOMAIN], 12, 48, 5)
    workers, stats = p.umc.call("candidates", DOMAIN, 0)
    word = workers[0]
    assert word >> 255 == 1
    assert (
        word & ((1 << 160) - 1),
        (word >> 160) & 0xFF,
        (word >> 168) & 0xFF,
        (word >> 176) & 0xFFFF,
        (word >> 192) & 0xFFFF,
    ) == (int(w, 16), 1, 5, 12, 48)
    assert stats == [0]
    ws, _ = p.umc.call("profiles", [1, 0], DOMAIN + 1, 1)
    assert ws[0] >> 255 == 0 and ws[1] == 0  # not in that domain; id 0 (nobody)
    assert (word >> 208) & 0xFFFFFFFF == 1  # candidate words carry the worker id
    assert p.umc.call("profiles", [1], DOMAIN, 0)[0][0] == word & ~(0xFFFFFFFF << 208)
