"""Model provenance (thesis 7.7): an outcome CID is recorded once with its worker and task,
only that worker may list it on the MMC and only once its requester accepted it, and no CID
is listed twice."""

from __future__ import annotations

import pytest

from backend.chain.platform import TaskStatus, Verdict, cid_hash

from .conftest import ACCEPT_WINDOW, DOMAIN, REVIEW_WINDOW
from .helpers import CID, cid_for, reverts, two_accepted

REWARD = 10**15
ZERO = "0x" + "00" * 20


@pytest.fixture
def submitted(p, actors):
    """Task with two workers who accepted; W0 submitted CID (pending review)."""
    tid, offered = two_accepted(p, actors, DOMAIN, 2 * ACCEPT_WINDOW, REWARD)
    p.tmc.submit_outcome(offered[0], tid, CID)
    return p, tid, offered, [w for w in actors.workers[:3] if w not in offered]


def test_outcome_is_recorded_with_worker_task_and_verdict(submitted, actors) -> None:
    p, tid, (w0, w1), _ = submitted
    assert p.tmc.outcome_of(CID) == (w0, tid, Verdict.PENDING)
    assert p.tmc.outcome_of(cid_for("never")) == (ZERO, 0, Verdict.NONE)
    p.tmc.submit_outcome(w1, tid, cid_for("b"))
    p.tmc.transact("reviewOutcome", tid, w0, 4, True, sender=actors.requester)
    p.tmc.transact("reviewOutcome", tid, w1, 1, False, sender=actors.requester)
    assert p.tmc.outcome_of(CID)[2] == Verdict.ACCEPTED
    assert p.tmc.outcome_of(cid_for("b")) == (w1, tid, Verdict.REJECTED)
    assert p.tmc.offer(tid, w0)["paid"] and not p.tmc.offer(tid, w1)["paid"]


def test_an_outcome_cid_is_submitted_once(submitted) -> None:
    """A second worker cannot hand in the first one's model (nor anyone a CID twice)."""
    p, tid, (w0, w1), _ = submitted
    err = reverts("TasksDuplicateOutcome", p.tmc.transact, "submitOutcome", tid, CID, sender=w1)
    assert err.args_dict == {"taskId": tid, "worker": w0}
    assert p.tmc.offer(tid, w1)["state"] == 2  # still Accepted: it can submit its own


def test_only_the_outcomes_worker_may_share_it(submitted, actors) -> None:
    p, tid, (w0, w1), others = submitted
    p.tmc.transact("reviewOutcome", tid, w0, 5, True, sender=actors.requester)
    for thief in (w1, others[0]):
        err = reverts("ModelsNotOutcomeOwner", p.mmc.add_model, thief, CID, DOMAIN, [1])
        assert err.args_dict == {"taskId": tid, "worker": w0}
    mid, rc = p.mmc.add_model(w0, CID, DOMAIN, [1])
    assert rc.one("ModelAdded").args["owner"] == w0
    assert p.mmc.model_of_cid(CID) == mid


def test_pending_and_rejected_outcomes_are_not_shared(submitted, actors) -> None:
    p, tid, (w0, w1), _ = submitted
    err = reverts("ModelsOutcomeNotAccepted", p.mmc.add_model, w0, CID, DOMAIN, [1])
    assert err.args_dict == {"taskId": tid, "verdict": Verdict.PENDING}
    p.tmc.submit_outcome(w1, tid, cid_for("b"))
    p.tmc.transact("reviewOutcome", tid, w1, 0, False, sender=actors.requester)
    err = reverts("ModelsOutcomeNotAccepted", p.mmc.add_model, w1, cid_for("b"), DOMAIN, [1])
    assert err.args_dict["verdict"] == Verdict.REJECTED
    assert p.mmc.call("modelCount") == 0


def test_outcome_paid_unreviewed_at_close_may_be_shared(submitted, chain_session) -> None:
    p, tid, (w0, _), _ = submitted
    chain_session.advance_time(2 * ACCEPT_WINDOW + REVIEW_WINDOW + 1)
    p.tmc.transact("updateTaskStatus", tid, int(TaskStatus.CLOSED), sender=w0)
    assert p.tmc.outcome_of(CID)[2] == Verdict.ACCEPTED
    p.mmc.add_model(w0, CID, DOMAIN, [1])


def test_a_cid_is_listed_once(p, actors) -> None:
    ws = actors.workers[:2]
    for w in ws:
        p.umc.add_worker(w, [DOMAIN], 4, 16, 1)
    mid, _ = p.mmc.add_model(ws[0], CID, DOMAIN, [1, 2])  # an own upload: no outcome
    for w in ws:
        err = reverts("ModelsDuplicateModel", p.mmc.add_model, w, CID, DOMAIN, [1, 2])
        assert err.args_dict == {"modelId": mid}
    assert p.mmc.call("domainModels", DOMAIN) == [mid]
    assert p.mmc.model_of_cid(CID) == mid and p.mmc.call("modelOfCid", cid_hash(cid_for("x"))) == 0
