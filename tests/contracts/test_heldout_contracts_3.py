"""Held-out attack pass 3 on the contracts (docs/chain.md, "Held-out pass of 2026-12-04").

An outsider signing its own transactions tried the roles' checks, griefing, payments,
reputation and integer edges on the real EVM. One defect was found and fixed, replayed here:

Attacks that held are replayed too (docs/chain.md lists them): the edges below and a
commitment made for someone else.

* A slot held to the deadline is rated 0 at close (docs/chain.md, "Offers that count": holding
  a slot must cost more than giving it back in time). A worker that held its slot until the
  last second and then gave it back (`abandonOffer`) escaped that rating: the slot was just as
  held (nobody else could be offered it any more), yet the worker's rating was untouched. Now
  a give-back too late for the slot to be offered again is rated 0, as the close rates it.
"""

from __future__ import annotations

import pytest

from backend.chain.platform import Metric, OfferState, TaskStatus, cid_commitment

from .conftest import ACCEPT_WINDOW, DOMAIN, REVIEW_WINDOW
from .helpers import cid_for, reverts

REWARD = 10**15
DURATION = 4 * ACCEPT_WINDOW


@pytest.fixture
def setup(p, actors):
    p.umc.add_requester(actors.requester)
    worker = actors.workers[0]
    p.umc.add_worker(worker, [DOMAIN], 8, 32, 1)
    return p, actors.requester, worker


def _held(p, r: str, w: str) -> int:
    """A one-slot task offered to ``w`` and accepted by it."""
    tid, _ = p.tmc.add_task(r, domain=DOMAIN, num_workers=1, reward=REWARD, duration=DURATION)
    assert p.tmc.allocate(r, tid)[0] == [w]
    p.tmc.transact("acceptOffer", tid, sender=w)
    return tid


def _rating(p, w: str) -> tuple[int, int]:
    c = p.umc.counters(w, DOMAIN, 0)
    return c["rating_sum"], c["rating_count"]


def _too_late_to_offer(p, tid: int) -> bool:
    slack = int(p.tmc.call("acceptWindow")) + int(p.tmc.call("minWorkTime"))
    return p.chain.now() + 1 + slack > p.tmc.task(tid)["deadline"]


def test_a_slot_held_to_the_last_second_is_rated_as_held(setup) -> None:
    """Holding a slot to the deadline is rated 0 at close; giving it back at the last second
    was not rated at all (before the fix: rating count 0 after the late give-back). Now it is
    rated 0 as soon as the slot can no longer go to anyone else; a give-back in time (the
    requester can still offer the slot) stays unrated."""
    p, r, w = setup

    # in time: unrated, and the requester offers the slot again
    early = _held(p, r, w)
    rc = p.tmc.transact("abandonOffer", early, sender=w)
    assert rc.named("WorkerInfoUpdated") == []
    assert _rating(p, w) == (0, 0)

    # held to the deadline and closed: rated 0 (the rule the late give-back dodged)
    held = _held(p, r, w)
    p.chain.advance_time(DURATION + 1)
    p.tmc.transact("updateTaskStatus", held, TaskStatus.CLOSED.value, sender=r)
    assert p.tmc.offer(held, w)["state"] == OfferState.FAILED
    assert _rating(p, w) == (0, 1)

    # held until no other worker could be offered the slot, then given back
    late = _held(p, r, w)
    p.chain.advance_time(DURATION - 10)
    assert _too_late_to_offer(p, late)
    rc = p.tmc.transact("abandonOffer", late, sender=w)
    assert p.tmc.offer(late, w)["state"] == OfferState.FAILED
    assert [e.args["worker"] for e in rc.named("OfferFailed")] == [w]
    assert _rating(p, w) == (0, 2), "a slot given back too late to be offered again is held"
    ev = rc.one("WorkerInfoUpdated").args
    assert (ev["worker"], ev["ratingSum"], ev["ratingCount"]) == (w, 0, 2)
    # the counters of Eq. 17-18 are those of any give-back: accepted, never completed
    c = p.umc.counters(w, DOMAIN, 0)
    assert (c["assigned"], c["accepted"], c["completed"]) == (3, 3, 0)
    # the slot is free: the requester takes its escrow back at close, as before
    p.chain.advance_time(REVIEW_WINDOW + 20)
    p.tmc.transact("updateTaskStatus", late, TaskStatus.CLOSED.value, sender=r)
    assert _rating(p, w) == (0, 2)  # rated once, not again at the close


def test_integer_edges_and_self_allocation_are_refused(setup, actors) -> None:
    """0 workers, 0 payment, a duration below the least one, and (a requester that owns
    the domain's only model) its own model: each refused with its custom error. The longest
    duration the admin may set (2^32 - 1 s) posts a task whose review end still fits."""
    p, r, w = setup
    tmc = p.tmc
    reverts(
        "TasksBadWorkerCount",
        tmc.add_task,
        r,
        domain=DOMAIN,
        num_workers=0,
        reward=1,
        duration=DURATION,
    )
    reverts(
        "TasksRewardBelowMinimum",
        tmc.add_task,
        r,
        domain=DOMAIN,
        num_workers=1,
        reward=0,
        duration=DURATION,
    )
    reverts("TasksBadDuration", tmc.add_task, r, domain=DOMAIN, num_workers=1, reward=1, duration=0)
    tmc.set_task_limits(actors.admin, 60, 2**32 - 1)
    tid, rc = tmc.add_task(r, domain=DOMAIN, num_workers=1, reward=1, duration=2**32 - 1)
    t = tmc.task(tid)
    assert t["deadline"] == rc.one("TaskAdded").args["deadline"] == p.chain.now() + 2**32 - 1
    assert t["review_end"] == t["deadline"] + REVIEW_WINDOW

    # a worker that is also a requester is never allocated its own model
    p.umc.add_requester(w)
    p.mmc.add_model(w, cid_for("own"), DOMAIN, [1, 2])
    reverts("ModelsBadModelCount", p.mmc.allocate, w, domain=DOMAIN, num_models=0, env=[1, 2])
    reverts(
        "ModelsPriceBelowMinimum",
        p.mmc.allocate,
        w,
        domain=DOMAIN,
        num_models=1,
        env=[1, 2],
        price=0,
    )
    for metric in (Metric.MODEL, Metric.SHARING):
        reverts(
            "ModelsNoEligibleModel",
            p.mmc.allocate,
            w,
            domain=DOMAIN,
            num_models=1,
            env=[1, 2],
            metric=metric,
        )
    _, models, _ = p.mmc.allocate(r, domain=DOMAIN, num_models=1, env=[1, 2])
    assert len(models) == 1  # another requester gets it


def test_a_commitment_made_for_someone_else_only_helps_it(setup, actors) -> None:
    """commitCid stores any commitment: a worker that knows a CID can commit
    keccak256(cid ++ victim). The victim may then reveal it; the committer cannot (its own
    commitment is another hash), and nothing of the victim's is spent or overwritten."""
    p, r, victim = setup
    tid = _held(p, r, victim)
    other = actors.workers[1]
    p.umc.add_worker(other, [DOMAIN], 16, 32, 1)  # offered the next task before the victim
    cid = cid_for("victim's outcome")
    commitment = cid_commitment(cid, victim)
    rc = p.tmc.transact("commitCid", commitment, sender=other)
    assert rc.one("CidCommitted").args["worker"] == other  # the sender, not the victim
    p.chain.advance_time(1)
    tid2, _ = p.tmc.add_task(r, domain=DOMAIN, num_workers=1, reward=REWARD, duration=DURATION)
    assert p.tmc.allocate(r, tid2)[0] == [other]
    p.tmc.transact("acceptOffer", tid2, sender=other)
    reverts("TasksCidNotCommitted", p.tmc.transact, "submitOutcome", tid2, cid, sender=other)
    p.tmc.transact("submitOutcome", tid, cid, sender=victim)
    assert p.tmc.outcome_of(cid)[0] == victim
