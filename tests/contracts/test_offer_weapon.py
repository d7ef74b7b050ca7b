"""Offers that count (docs/chain.md): reputation moves only on what a worker did.

The audit of 2026-12-03 found three ways the counters of Eq. 16-19 lied: a requester's offers,
declined or left to expire and then cancelled, lowered a worker's reputation for free; a
rejected outcome counted as completed; holding a slot to the deadline cost what declining
cost. These tests replay each on the embedded chain with the Python wrapper a gateway uses."""

from __future__ import annotations

import pytest

from backend.chain import qos
from backend.chain.platform import TaskStatus

from .conftest import ACCEPT_WINDOW, DOMAIN, REVIEW_WINDOW
from .helpers import cid_for

REWARD = 10**15
DURATION = 3 * ACCEPT_WINDOW


@pytest.fixture
def setup(p, actors):
    p.umc.add_requester(actors.requester)
    p.umc.add_requester(actors.other_requester)
    victim, rival = actors.workers[0], actors.workers[1]
    p.umc.add_worker(victim, [DOMAIN], 64, 64, 1)  # the best QoS: offered first
    p.umc.add_worker(rival, [DOMAIN], 2, 64, 1)
    return p, actors, victim, rival


def _task(p, requester: str) -> int:
    tid, _ = p.tmc.add_task(
        requester, domain=DOMAIN, num_workers=1, reward=REWARD, duration=DURATION
    )
    return tid


def _good_history(p, requester: str, worker: str) -> None:
    """One task accepted, delivered and accepted by its requester: reputation 1.0."""
    tid = _task(p, requester)
    assert p.tmc.allocate(requester, tid)[0] == [worker]
    p.tmc.transact("acceptOffer", tid, sender=worker)
    p.tmc.submit_outcome(worker, tid, cid_for(("history", tid)))
    p.tmc.transact("reviewOutcome", tid, worker, 5, True, sender=requester)


def _reputation(p, w: str) -> int:
    c = p.umc.counters(w, DOMAIN, 0)
    return qos.reputation_fixed(c["assigned"], c["accepted"], c["completed"])


def test_offers_made_to_be_refused_cost_the_worker_nothing(setup) -> None:
    """The audit's attack: tasks offered, refused (declined or ignored), then cancelled, their
    slots cancelled, or closed after their deadline. Before the fix the victim's reputation
    fell from 1.0 towards 0 with every such task; now every offer is taken back."""
    p, act, victim, _ = setup
    _good_history(p, act.other_requester, victim)
    before = p.umc.counters(victim, DOMAIN, 0)
    assert _reputation(p, victim) == qos.ONE
    attacker = act.requester
    tids = [_task(p, attacker) for _ in range(6)]
    for i, tid in enumerate(tids):
        assert p.tmc.allocate(attacker, tid)[0] == [victim]
        if i % 2:
            p.tmc.transact("declineOffer", tid, sender=victim)
    # while the offers are live they count (the worker may still accept them)
    assert p.umc.counters(victim, DOMAIN, 0)["assigned"] == before["assigned"] + len(tids)
    assert _reputation(p, victim) < qos.ONE
    p.chain.advance_time(ACCEPT_WINDOW + 30)
    for tid in tids[:2]:
        rc = p.tmc.transact("updateTaskStatus", tid, TaskStatus.CANCELLED.value, sender=attacker)
        assert [e.args["assigned"] for e in rc.named("WorkerInfoUpdated")] == [
            p.umc.counters(victim, DOMAIN, 0)["assigned"]
        ]
    for tid in tids[2:4]:
        p.tmc.cancel_open_slots(attacker, tid)
    p.chain.advance_time(DURATION + REVIEW_WINDOW)
    for tid in tids[4:]:
        p.tmc.transact("updateTaskStatus", tid, TaskStatus.CLOSED.value, sender=attacker)
    assert p.umc.counters(victim, DOMAIN, 0) == before
    assert _reputation(p, victim) == qos.ONE
    assert all(not p.tmc.task(t)["taken"] for t in tids)


def test_an_offer_lost_to_another_worker_still_counts(setup) -> None:
    """Eq. 17 as the thesis means it: the victim let the offer expire, the next best took the
    task; the expired offer stays in A and the victim's reputation falls."""
    p, act, victim, rival = setup
    _good_history(p, act.other_requester, victim)
    tid = _task(p, act.requester)
    assert p.tmc.allocate(act.requester, tid)[0] == [victim]
    p.chain.advance_time(ACCEPT_WINDOW + 30)
    assert p.tmc.allocate(act.requester, tid)[0] == [rival]
    p.tmc.transact("acceptOffer", tid, sender=rival)
    assert p.tmc.task(tid)["taken"]
    p.chain.advance_time(DURATION + REVIEW_WINDOW)
    p.tmc.transact("updateTaskStatus", tid, TaskStatus.CLOSED.value, sender=act.requester)
    c = p.umc.counters(victim, DOMAIN, 0)
    assert (c["assigned"], c["accepted"], c["completed"]) == (2, 1, 1)
    assert _reputation(p, victim) == qos.reputation_fixed(2, 1, 1) < qos.ONE
    # the rival held its slot to the deadline without an outcome: rated 0, not completed
    r = p.umc.counters(rival, DOMAIN, 0)
    assert r == {"assigned": 1, "accepted": 1, "completed": 0, "rating_sum": 0, "rating_count": 1}


def test_completed_means_accepted_or_paid(setup) -> None:
    """A rejected outcome is rated, not completed (E of Eq. 18, N of Eq. 16 of Eq. 21's
    expertise); an outcome the requester never reviewed is completed when it is paid."""
    p, act, victim, _ = setup
    _good_history(p, act.other_requester, victim)  # so it, not the newcomer, is offered first
    r = act.requester
    rejected, unreviewed = _task(p, r), _task(p, r)
    for tid in (rejected, unreviewed):
        assert p.tmc.allocate(r, tid)[0] == [victim]
        p.tmc.transact("acceptOffer", tid, sender=victim)
        p.tmc.submit_outcome(victim, tid, cid_for(("outcome", tid)))
    assert p.umc.counters(victim, DOMAIN, 0)["completed"] == 1  # submitted is not completed
    p.tmc.transact("reviewOutcome", rejected, victim, 2, False, sender=r)
    c = p.umc.counters(victim, DOMAIN, 0)
    assert (c["completed"], c["rating_sum"], c["rating_count"]) == (1, 5 + 2, 2)
    p.chain.advance_time(DURATION + REVIEW_WINDOW + 30)
    rc = p.tmc.transact("updateTaskStatus", unreviewed, TaskStatus.CLOSED.value, sender=victim)
    assert rc.one("OutcomeReviewed").args["accepted"] is True
    c = p.umc.counters(victim, DOMAIN, 0)
    assert (c["assigned"], c["accepted"], c["completed"], c["rating_count"]) == (3, 3, 2, 2)
    assert p.tmc.call("credits", victim) == 2 * REWARD  # the history task and the unreviewed one
