"""Issue 8, finding 6: escrow is bounded in time, and unfilled slots can be given up.

One accepting worker used to freeze the whole escrow until the deadline (up to ~136 years):
now the duration is bounded by the admin-set maxDuration, and the requester refunds every
slot nobody holds with cancelOpenSlots while accepted workers keep theirs."""

from __future__ import annotations

import pytest

from backend.chain.platform import OfferState, TaskStatus

from .conftest import ACCEPT_WINDOW, DOMAIN
from .helpers import CID, reverts

REWARD = 10**15
DAY = 86_400
MAX_DURATION = 30 * DAY  # TasksManager.DEFAULT_MAX_DURATION


@pytest.fixture
def setup(p, actors):
    """Requester and three workers (cores 16 > 8 > 4: offers go in that order)."""
    p.umc.add_requester(actors.requester)
    ws = actors.workers[:3]
    for addr, cores in zip(ws, (16, 8, 4), strict=True):
        p.umc.add_worker(addr, [DOMAIN], cores, 32, 1)
    return p, actors.requester, ws


def _task(p, r, nw: int, duration: int = DAY) -> int:
    return p.tmc.add_task(r, domain=DOMAIN, num_workers=nw, reward=REWARD, duration=duration)[0]


def _escrow_held(p, accounts) -> None:
    """Conservation: the TMC holds exactly its credits plus the unsettled slots' rewards."""
    held = sum(p.tmc.call("credits", a) for a in accounts)
    for tid in range(1, p.tmc.call("taskCount") + 1):
        t = p.tmc.task(tid)
        if t["status"] == TaskStatus.OPEN:
            held += (t["num_workers"] - t["settled"]) * t["reward"]
    assert p.chain.balance(p.tmc.address) == held


def test_duration_is_bounded(setup) -> None:
    p, r, _ = setup
    for duration in (MAX_DURATION + 1, 2**32 - 1):
        err = reverts("TasksBadDuration", _task, p, r, 1, duration)
        assert err.args_dict["maximum"] == MAX_DURATION
    assert p.tmc.task(_task(p, r, 1, MAX_DURATION))["status"] == TaskStatus.OPEN


def test_unfilled_slots_are_refunded_while_accepted_workers_keep_theirs(setup, actors) -> None:
    p, r, ws = setup
    everyone = [r, *ws]
    tid = _task(p, r, 3)
    p.tmc.allocate(r, tid)
    p.tmc.transact("acceptOffer", tid, sender=ws[0])
    p.tmc.transact("declineOffer", tid, sender=ws[1])
    # ws[2] holds a live offer: only the declined slot can go
    cancelled, rc = p.tmc.cancel_open_slots(r, tid)
    assert cancelled == 1
    assert rc.one("SlotsCancelled").args == {"taskId": tid, "cancelled": 1, "numWorkers": 2}
    assert rc.one("PaymentCredited").args == {"account": r, "taskId": tid, "amount": REWARD}
    assert p.tmc.task(tid)["num_workers"] == 2
    _escrow_held(p, everyone)
    reverts("TasksNoOpenSlot", p.tmc.cancel_open_slots, r, tid)
    p.chain.advance_time(ACCEPT_WINDOW + 1)  # ws[2] let its offer lapse
    cancelled, rc = p.tmc.cancel_open_slots(r, tid)
    assert cancelled == 1 and rc.one("OfferExpired").args["worker"] == ws[2]
    assert p.tmc.offer(tid, ws[2])["state"] == OfferState.EXPIRED
    t = p.tmc.task(tid)
    assert (t["num_workers"], t["filled"], t["live_offers"], t["status"]) == (
        1,
        1,
        0,
        TaskStatus.OPEN,
    )
    assert p.tmc.call("credits", r) == 2 * REWARD
    _escrow_held(p, everyone)
    # the accepted worker still delivers and is paid; the task completes on its review
    p.tmc.submit_outcome(ws[0], tid, CID)
    rc = p.tmc.transact("reviewOutcome", tid, ws[0], 5, True, sender=r)
    assert rc.one("TaskStatusUpdated").args["status"] == TaskStatus.COMPLETED
    assert p.tmc.call("credits", ws[0]) == REWARD
    _escrow_held(p, everyone)


def test_cancelling_every_slot_cancels_the_task(setup) -> None:
    p, r, ws = setup
    tid = _task(p, r, 2)
    cancelled, rc = p.tmc.cancel_open_slots(r, tid)  # never allocated
    assert cancelled == 2
    assert rc.one("TaskStatusUpdated").args["status"] == TaskStatus.CANCELLED
    assert p.tmc.task(tid)["status"] == TaskStatus.CANCELLED
    assert p.tmc.call("credits", r) == 2 * REWARD
    reverts("TasksNotOpen", p.tmc.cancel_open_slots, r, tid)
    _escrow_held(p, [r, *ws])


def test_cancelling_the_rest_after_the_reviews_completes_the_task(setup) -> None:
    p, r, ws = setup
    tid = _task(p, r, 2)
    p.tmc.allocate(r, tid)
    p.tmc.transact("acceptOffer", tid, sender=ws[0])
    p.tmc.transact("declineOffer", tid, sender=ws[1])
    p.tmc.submit_outcome(ws[0], tid, CID)
    p.tmc.transact("reviewOutcome", tid, ws[0], 4, True, sender=r)
    _, rc = p.tmc.cancel_open_slots(r, tid)
    assert rc.one("TaskStatusUpdated").args["status"] == TaskStatus.COMPLETED
    assert p.tmc.call("credits", r) == REWARD and p.tmc.call("credits", ws[0]) == REWARD
    _escrow_held(p, [r, *ws])


def test_an_abandoned_slot_can_be_cancelled(setup) -> None:
    p, r, ws = setup
    tid = _task(p, r, 1)
    p.tmc.allocate(r, tid)
    p.tmc.transact("acceptOffer", tid, sender=ws[0])
    reverts("TasksNoOpenSlot", p.tmc.cancel_open_slots, r, tid)  # the worker holds it
    p.tmc.transact("abandonOffer", tid, sender=ws[0])
    cancelled, _ = p.tmc.cancel_open_slots(r, tid)
    assert cancelled == 1 and p.tmc.task(tid)["status"] == TaskStatus.CANCELLED
    assert p.tmc.call("credits", r) == REWARD


def test_only_the_requester_cancels_slots_and_only_before_the_deadline(setup, actors) -> None:
    p, r, ws = setup
    tid = _task(p, r, 2)
    for who in (actors.admin, actors.other_requester, ws[0], actors.outsider):
        err = reverts("TasksNotTaskRequester", p.tmc.cancel_open_slots, who, tid)
        assert err.args_dict == {"taskId": tid, "account": who}
    reverts("TasksUnknownTask", p.tmc.cancel_open_slots, r, 999)
    p.chain.advance_time(DAY + 1)
    reverts("TasksDeadlinePassed", p.tmc.cancel_open_slots, r, tid)
