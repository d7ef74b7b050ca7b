"""Offers that count (docs/chain.md): reputation moves only on what a worker did.

The audit of 2026-12-03 found three ways the counters of Eq. 16-19 lied: a requester's offers,
declined or left to expire and then cancelled, lowered a worker's reputation for free; a
rejected outcome counted as completed; holding a slot to the deadline cost what declining
cost. A later audit found that offers still lowered a reputation while their task ran (a decoy
task never cancelled) and for good once an accomplice had accepted and given its slot back:
an offer now counts only once accepted, or at its task's end if a worker held a slot then.
These tests replay each on the embedded chain with the Python wrapper a gateway uses."""

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
    fell from 1.0 towards 0 with every such task; now no such offer ever counts."""
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
    # while the tasks run, neither the live offers nor the declined ones count
    assert p.umc.counters(victim, DOMAIN, 0) == before
    assert _reputation(p, victim) == qos.ONE
    p.chain.advance_time(ACCEPT_WINDOW + 30)
    for tid in tids[:2]:
        rc = p.tmc.transact("updateTaskStatus", tid, TaskStatus.CANCELLED.value, sender=attacker)
        assert rc.named("WorkerInfoUpdated") == []  # nobody held a slot: nothing counts
    for tid in tids[2:4]:
        p.tmc.cancel_open_slots(attacker, tid)
    p.chain.advance_time(DURATION + REVIEW_WINDOW)
    for tid in tids[4:]:
        p.tmc.transact("updateTaskStatus", tid, TaskStatus.CLOSED.value, sender=attacker)
    assert p.umc.counters(victim, DOMAIN, 0) == before
    assert _reputation(p, victim) == qos.ONE
    assert all(p.tmc.task(t)["filled"] == 0 for t in tids)


def test_a_decoy_task_left_open_costs_the_worker_nothing(setup) -> None:
    """The decoy: a long task only the victim qualifies for, declined, never cancelled. A fresh
    victim keeps the new worker's 0.5 while it runs (before the fix: 0), so a task asking for
    minReputation 0.5 still offers it work; closed with nobody holding a slot, it never counts."""
    p, act, victim, _ = setup
    attacker = act.requester
    decoy, _ = p.tmc.add_task(
        attacker,
        domain=DOMAIN,
        num_workers=1,
        reward=REWARD,
        duration=30 * 86_400,
        min_cpu_cores=64,
    )
    assert p.tmc.allocate(attacker, decoy)[0] == [victim]
    p.tmc.transact("declineOffer", decoy, sender=victim)
    p.chain.advance_time(20 * 86_400)
    assert _reputation(p, victim) == qos.ONE // 2
    honest, _ = p.tmc.add_task(
        act.other_requester,
        domain=DOMAIN,
        num_workers=1,
        reward=REWARD,
        duration=DURATION,
        min_reputation=qos.ONE // 2,
        min_cpu_cores=64,
    )
    assert p.tmc.allocate(act.other_requester, honest)[0] == [victim]
    p.chain.advance_time(10 * 86_400 + 30)
    p.tmc.transact("updateTaskStatus", decoy, TaskStatus.CLOSED.value, sender=attacker)
    assert p.umc.counters(victim, DOMAIN, 0)["assigned"] == 0


def test_an_accomplice_who_gives_its_slot_back_makes_nothing_count(setup) -> None:
    """The second finding: an accomplice accepts a slot and gives it back at once
    (abandonOffer, never rated); the requester cancels. Before the fix the task stayed
    `taken` and the victim's declined offer counted for good; now nobody held a slot at the
    end, so it does not. The accomplice's own accept counts (assigned and accepted)."""
    p, act, victim, accomplice = setup
    tid, _ = p.tmc.add_task(
        act.requester, domain=DOMAIN, num_workers=2, reward=REWARD, duration=DURATION
    )
    assert set(p.tmc.allocate(act.requester, tid)[0]) == {victim, accomplice}
    p.tmc.transact("declineOffer", tid, sender=victim)
    p.tmc.transact("acceptOffer", tid, sender=accomplice)
    p.tmc.transact("abandonOffer", tid, sender=accomplice)
    p.tmc.transact("updateTaskStatus", tid, TaskStatus.CANCELLED.value, sender=act.requester)
    assert p.tmc.task(tid)["status"] == TaskStatus.CANCELLED
    assert p.umc.counters(victim, DOMAIN, 0)["assigned"] == 0
    c = p.umc.counters(accomplice, DOMAIN, 0)
    assert (c["assigned"], c["accepted"], c["completed"], c["rating_count"]) == (1, 1, 0, 0)


def test_a_task_its_workers_completed_counts_the_offers_they_did_not_take(setup) -> None:
    """A task completed by its workers (last review) counts the offers made on it that were
    declined or expired: those workers lost a task that found workers (Eq. 17)."""
    p, act, victim, rival = setup
    worker = act.workers[2]
    p.umc.add_worker(worker, [DOMAIN], 32, 64, 1)
    r = act.requester
    tid, _ = p.tmc.add_task(r, domain=DOMAIN, num_workers=2, reward=REWARD, duration=DURATION)
    assert p.tmc.allocate(r, tid)[0] == [victim, worker]
    p.tmc.transact("declineOffer", tid, sender=victim)
    p.tmc.transact("acceptOffer", tid, sender=worker)
    assert p.tmc.allocate(r, tid)[0] == [rival]
    p.chain.advance_time(ACCEPT_WINDOW + 30)  # the rival lets its offer expire
    p.tmc.cancel_open_slots(r, tid)
    p.tmc.submit_outcome(worker, tid, cid_for(("done", tid)))
    assert p.umc.counters(victim, DOMAIN, 0)["assigned"] == 0  # not before the end
    rc = p.tmc.transact("reviewOutcome", tid, worker, 4, True, sender=r)
    assert rc.one("TaskStatusUpdated").args["status"] == TaskStatus.COMPLETED.value
    for w in (victim, rival):
        c = p.umc.counters(w, DOMAIN, 0)
        assert (c["assigned"], c["accepted"], c["completed"]) == (1, 0, 0)
        assert _reputation(p, w) == 0
    c = p.umc.counters(worker, DOMAIN, 0)
    assert (c["assigned"], c["accepted"], c["completed"]) == (1, 1, 1)


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
    assert p.umc.counters(victim, DOMAIN, 0)["assigned"] == 1  # the history task only, yet
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
    assert rc.one("OutcomePaidUnreviewed").args["worker"] == victim  # paid, no review
    assert rc.named("OutcomeReviewed") == []  # not a review of 0
    c = p.umc.counters(victim, DOMAIN, 0)
    assert (c["assigned"], c["accepted"], c["completed"], c["rating_count"]) == (3, 3, 2, 2)
    assert p.tmc.call("credits", victim) == 2 * REWARD  # the history task and the unreviewed one
