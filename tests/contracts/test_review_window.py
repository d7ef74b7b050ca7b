"""Issue 8, finding 5: the requester reviews until deadline + reviewWindow, never after.

Past the review window an unreviewed outcome is the worker's (paid at close); a rejection
then would take back money the worker is owed."""

from __future__ import annotations

import pytest

from backend.chain.platform import OfferState, TaskStatus

from .conftest import DOMAIN, REVIEW_WINDOW
from .helpers import CID, reverts

REWARD = 10**15
DAY = 86_400
MARGIN = 30


@pytest.fixture
def submitted(p, actors):
    """One-slot task whose worker has submitted; returns (platform, requester, worker, task)."""
    p.umc.add_requester(actors.requester)
    w = actors.workers[0]
    p.umc.add_worker(w, [DOMAIN], 8, 32, 1)
    r = actors.requester
    tid, _ = p.tmc.add_task(r, domain=DOMAIN, num_workers=1, reward=REWARD, duration=DAY)
    p.tmc.allocate(r, tid)
    p.tmc.transact("acceptOffer", tid, sender=w)
    p.tmc.submit_outcome(w, tid, CID)
    return p, r, w, tid


def test_rejection_after_the_review_window_reverts_and_the_worker_is_paid(submitted) -> None:
    p, r, w, tid = submitted
    deadline = p.tmc.task(tid)["deadline"]
    p.chain.advance_time(DAY + REVIEW_WINDOW + MARGIN)
    err = reverts(
        "TasksReviewWindowClosed", p.tmc.transact, "reviewOutcome", tid, w, 0, False, sender=r
    )
    assert err.args_dict == {"taskId": tid, "reviewEnd": deadline + REVIEW_WINDOW}
    assert p.tmc.call("credits", r) == 0
    p.tmc.transact("updateTaskStatus", tid, int(TaskStatus.CLOSED), sender=w)
    assert p.tmc.call("credits", w) == REWARD and p.tmc.call("credits", r) == 0
    o = p.tmc.offer(tid, w)
    assert o["state"] == OfferState.REVIEWED and o["paid"]


def test_rejection_inside_the_review_window_still_refunds(submitted) -> None:
    p, r, w, tid = submitted
    p.chain.advance_time(DAY + REVIEW_WINDOW - MARGIN)  # after the deadline, window still open
    p.tmc.transact("reviewOutcome", tid, w, 1, False, sender=r)
    assert p.tmc.call("credits", r) == REWARD and p.tmc.call("credits", w) == 0
    assert p.tmc.task(tid)["status"] == TaskStatus.COMPLETED
