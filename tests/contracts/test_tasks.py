"""TMC (Tasks Manager): every function and revert path of the training-task life cycle."""

from __future__ import annotations

import pytest

from backend.chain.platform import OfferState, TaskStatus

from .conftest import ACCEPT_WINDOW, DOMAIN, REVIEW_WINDOW
from .helpers import CID, reverts

REWARD = 10**15
DAY = 86_400


@pytest.fixture
def setup(p, actors):
    """Requester, three workers (cores 16 > 8 > 4, so offers go in that order)."""
    p.umc.add_requester(actors.requester)
    ws = actors.workers[:3]
    for addr, cores in zip(ws, (16, 8, 4), strict=True):
        p.umc.add_worker(addr, [DOMAIN], cores, 32, 1)
    return p, actors.requester, ws


def _task(p, r, nw=2, duration=DAY, **kw):
    return p.tmc.add_task(r, domain=DOMAIN, num_workers=nw, reward=REWARD, duration=duration, **kw)[
        0
    ]


def test_add_task_escrows_and_validates(setup, actors) -> None:
    p, r, _ = setup
    before = p.chain.balance(p.tmc.address)
    tid, rc = p.tmc.add_task(
        r,
        domain=DOMAIN,
        num_workers=3,
        reward=REWARD,
        duration=DAY,
        description="target localization",
    )
    ev = rc.one("TaskAdded").args
    assert (ev["reward"], ev["numWorkers"], ev["description"]) == (REWARD, 3, "target localization")
    assert p.chain.balance(p.tmc.address) - before == 3 * REWARD
    t = p.tmc.task(tid)
    assert (t["status"], t["requester"], t["deadline"]) == (TaskStatus.OPEN, r, ev["deadline"])
    assert p.tmc.call("domainTasks", DOMAIN) == [tid]

    def send(value: int = 0, **o: int) -> None:
        base = {
            "d": DOMAIN,
            "nw": 1,
            "rep": 0,
            "rat": 0,
            "cpu": 0,
            "ram": 0,
            "dur": DAY,
            "desc": "",
        }
        p.tmc.transact("addTask", tuple((base | o).values()), sender=r, value=value)

    reverts("TasksBadWorkerCount", send, nw=0)
    reverts("TasksBadWorkerCount", send, nw=17)
    reverts("TasksBadDomain", send, d=256)
    reverts("TasksBadThreshold", send, rep=1_000_001)
    reverts("TasksBadThreshold", send, rat=1_000_001)
    reverts("TasksBadDuration", send, dur=0)
    reverts("TasksBadDuration", send, dur=2**32)
    reverts("TasksBadPayment", send, value=5, nw=2)


def test_allocate_offers_best_and_refills(setup, actors) -> None:
    p, r, ws = setup
    tid = _task(p, r, nw=2)
    offered, rc = p.tmc.allocate(r, tid)
    assert offered == ws[:2]
    assert rc.one("TaskAllocated").args["offered"] == 2
    o = p.tmc.offer(tid, ws[0])
    assert o["state"] == OfferState.OFFERED and o["expiry"] == p.chain.now() + ACCEPT_WINDOW
    assert p.umc.counters(ws[0], DOMAIN, 0)["assigned"] == 0  # counted once accepted or at the end
    reverts("TasksNoOpenSlot", p.tmc.allocate, r, tid)
    p.tmc.transact("declineOffer", tid, sender=ws[0])
    assert p.tmc.offer(tid, ws[0])["state"] == OfferState.DECLINED
    assert p.tmc.allocate(actors.admin, tid)[0] == [ws[2]]  # admins may allocate too
    offered, rc = p.tmc.allocate(r, (tid2 := _task(p, r, nw=1, min_cpu_cores=64)))
    assert offered == [] and rc.one("TaskAllocated").args["offered"] == 0
    assert p.tmc.task(tid2)["live_offers"] == 0


def test_gpu_series_and_config_are_admin_settings(setup, actors) -> None:
    p, r, ws = setup
    admin = actors.admin
    rc = p.tmc.transact("setGpuSeries", 1, False, sender=admin)
    assert rc.one("AcceptedGpusUpdated").args["mask"] == 0b1100  # {2, 3} left of {1, 2, 3}
    assert p.tmc.call("acceptedGpus") == 0b1100
    assert p.tmc.allocate(r, _task(p, r, nw=1))[0] == []  # every worker has series 1
    p.tmc.transact("setGpuSeries", 1, True, sender=admin)
    rc = p.tmc.transact("setConfig", 5_000_000, 60, 120, sender=admin)
    assert rc.one("ConfigUpdated").args == {
        "w1": 5_000_000,
        "acceptWindow": 60,
        "reviewWindow": 120,
    }
    reverts("TasksBadConfig", p.tmc.transact, "setConfig", 0, 60, 120, sender=admin)
    reverts("TasksBadConfig", p.tmc.transact, "setConfig", 10**12 + 1, 60, 120, sender=admin)
    reverts("TasksBadConfig", p.tmc.transact, "setConfig", 1, 0, 120, sender=admin)
    reverts("TasksBadConfig", p.tmc.transact, "setConfig", 1, 60, 0, sender=admin)


def test_accept_decline_submit_reverts(setup, actors) -> None:
    p, r, ws = setup
    tid = _task(p, r, nw=2, duration=3 * ACCEPT_WINDOW)
    p.tmc.allocate(r, tid)
    reverts("TasksNotAssignedWorker", p.tmc.transact, "submitOutcome", tid, CID, sender=ws[0])
    p.tmc.transact("acceptOffer", tid, sender=ws[0])
    assert p.tmc.task(tid)["filled"] == 1
    reverts("TasksNotOfferedWorker", p.tmc.transact, "acceptOffer", tid, sender=ws[0])
    reverts("TasksNotOfferedWorker", p.tmc.transact, "declineOffer", tid, sender=ws[0])
    reverts("TasksEmptyCid", p.tmc.transact, "submitOutcome", tid, "", sender=ws[0])
    p.tmc.submit_outcome(ws[0], tid, CID)
    reverts("TasksNotAssignedWorker", p.tmc.transact, "submitOutcome", tid, CID, sender=ws[0])
    assert p.umc.counters(ws[0], DOMAIN, 0)["completed"] == 0  # counted once accepted
    p.chain.advance_time(ACCEPT_WINDOW + 1)
    err = reverts("TasksOfferExpired", p.tmc.transact, "acceptOffer", tid, sender=ws[1])
    assert err.args_dict["expiry"] == p.tmc.offer(tid, ws[1])["expiry"]
    p.chain.advance_time(2 * ACCEPT_WINDOW)
    reverts("TasksDeadlinePassed", p.tmc.allocate, r, tid)
    reverts("TasksDeadlinePassed", p.tmc.transact, "acceptOffer", tid, sender=ws[1])


def test_review_pays_once(setup, actors) -> None:
    p, r, ws = setup
    tid = _task(p, r, nw=1)
    p.tmc.allocate(r, tid)
    p.tmc.transact("acceptOffer", tid, sender=ws[0])
    reverts("TasksNotSubmitted", p.tmc.transact, "reviewOutcome", tid, ws[0], 3, True, sender=r)
    p.tmc.submit_outcome(ws[0], tid, CID)
    reverts("TasksBadReview", p.tmc.transact, "reviewOutcome", tid, ws[0], 6, True, sender=r)
    rc = p.tmc.transact("reviewOutcome", tid, ws[0], 3, True, sender=r)
    assert rc.one("PaymentCredited").args == {"account": ws[0], "taskId": tid, "amount": REWARD}
    assert p.tmc.task(tid)["status"] == TaskStatus.COMPLETED
    reverts("TasksNotSubmitted", p.tmc.transact, "reviewOutcome", tid, ws[0], 3, True, sender=r)
    assert p.umc.counters(ws[0], DOMAIN, 0)["rating_sum"] == 3
    before = p.chain.balance(ws[0])
    rc = p.tmc.transact("withdraw", sender=ws[0])
    assert p.chain.balance(ws[0]) == before + REWARD - rc.fee
    reverts("TasksNothingToWithdraw", p.tmc.transact, "withdraw", sender=ws[0])


def test_status_updates(setup, actors) -> None:
    p, r, ws = setup
    reverts(
        "TasksUnknownTask", p.tmc.transact, "updateTaskStatus", 99, int(TaskStatus.CLOSED), sender=r
    )
    tid = _task(p, r, nw=2)
    for bad in (TaskStatus.NONE, TaskStatus.OPEN, TaskStatus.COMPLETED):
        reverts("TasksBadStatus", p.tmc.transact, "updateTaskStatus", tid, int(bad), sender=r)
    reverts(
        "TasksDeadlineNotPassed",
        p.tmc.transact,
        "updateTaskStatus",
        tid,
        int(TaskStatus.CLOSED),
        sender=r,
    )
    p.tmc.allocate(r, tid)
    p.tmc.transact("acceptOffer", tid, sender=ws[0])
    reverts(
        "TasksHasAcceptedWorkers",
        p.tmc.transact,
        "updateTaskStatus",
        tid,
        int(TaskStatus.CANCELLED),
        sender=r,
    )
    t2 = _task(p, r, nw=2)
    rc = p.tmc.transact("updateTaskStatus", t2, int(TaskStatus.CANCELLED), sender=r)
    assert rc.one("PaymentCredited").args["amount"] == 2 * REWARD
    reverts(
        "TasksNotOpen", p.tmc.transact, "updateTaskStatus", t2, int(TaskStatus.CANCELLED), sender=r
    )
    reverts("TasksNotOpen", p.tmc.allocate, r, t2)
    # close: the accepted worker never submitted -> Failed; both slots refunded
    p.chain.advance_time(DAY + 1)
    rc = p.tmc.transact("updateTaskStatus", tid, int(TaskStatus.CLOSED), sender=actors.admin)
    assert p.tmc.offer(tid, ws[0])["state"] == OfferState.FAILED
    assert p.tmc.offer(tid, ws[1])["state"] == OfferState.EXPIRED
    assert rc.one("PaymentCredited").args["amount"] == 2 * REWARD
    assert p.tmc.call("credits", r) == 4 * REWARD
    reverts(
        "TasksNotOpen", p.tmc.transact, "updateTaskStatus", tid, int(TaskStatus.CLOSED), sender=r
    )
    assert REVIEW_WINDOW > 0


def test_requester_is_never_offered_its_own_task(setup, actors) -> None:
    p, r, ws = setup
    p.umc.add_worker(r, [DOMAIN], 64, 64, 1)  # the best worker of the pool
    offered, _ = p.tmc.allocate(r, _task(p, r, nw=2))
    assert r not in offered and offered == ws[:2]
    r2 = actors.other_requester
    p.umc.add_requester(r2)
    tid2, _ = p.tmc.add_task(r2, domain=DOMAIN, num_workers=1, reward=REWARD, duration=DAY)
    assert p.tmc.allocate(r2, tid2)[0] == [r]  # someone else's task: r is the best


def test_cancel_waits_for_live_offers(setup) -> None:
    p, r, ws = setup
    tid = _task(p, r, nw=1)
    p.tmc.allocate(r, tid)
    reverts(
        "TasksHasLiveOffers",
        p.tmc.transact,
        "updateTaskStatus",
        tid,
        int(TaskStatus.CANCELLED),
        sender=r,
    )
    p.tmc.transact("declineOffer", tid, sender=ws[0])
    p.tmc.transact("updateTaskStatus", tid, int(TaskStatus.CANCELLED), sender=r)
    assert p.tmc.task(tid)["status"] == TaskStatus.CANCELLED


def test_abandon_offer_fails_the_offer_and_reopens_the_slot(setup, actors) -> None:
    """A worker whose job failed gives the task back at once: Failed, slot open again, the
    requester may re-recruit (without it) or cancel; only the accepted worker may do it."""
    p, r, ws = setup
    tid = _task(p, r, nw=1)
    offered, _ = p.tmc.allocate(r, tid)
    w = offered[0]
    reverts("TasksNotAssignedWorker", p.tmc.transact, "abandonOffer", tid, sender=w)  # offered
    p.tmc.transact("acceptOffer", tid, sender=w)
    for other in (r, ws[1], actors.workers[5]):
        reverts("TasksNotAssignedWorker", p.tmc.transact, "abandonOffer", tid, sender=other)
    counters = p.umc.counters(w, DOMAIN, 0)
    rc = p.tmc.transact("abandonOffer", tid, sender=w)
    assert [(e.args["taskId"], e.args["worker"]) for e in rc.named("OfferFailed")] == [(tid, w)]
    assert p.tmc.offer(tid, w)["state"] == OfferState.FAILED
    assert p.tmc.task(tid)["filled"] == 0
    assert p.umc.counters(w, DOMAIN, 0) == counters  # still accepted, never completed
    reverts("TasksNotAssignedWorker", p.tmc.transact, "abandonOffer", tid, sender=w)  # once
    reverts("TasksNotAssignedWorker", p.tmc.transact, "submitOutcome", tid, CID, sender=w)
    again, _ = p.tmc.allocate(r, tid)
    assert again and w not in again
    p.tmc.transact("declineOffer", tid, sender=again[0])
    before = p.tmc.call("credits", r)
    p.tmc.transact("updateTaskStatus", tid, int(TaskStatus.CANCELLED), sender=r)
    assert p.tmc.call("credits", r) - before == REWARD
