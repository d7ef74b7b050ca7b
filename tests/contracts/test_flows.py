"""Complete training-task and model-sharing flows on both backends (embedded py-evm and
anvil over JSON-RPC), with payment conservation: every wei escrowed ends with a worker or
back with the requester, nothing stays in the contracts after withdrawals."""

from __future__ import annotations

from backend.chain import errors
from backend.chain.client import Chain
from backend.chain.platform import Metric, OfferState, TaskStatus, WorkerStatus

from .conftest import ACCEPT_WINDOW, DOMAIN, REVIEW_WINDOW, actors_of, make_platform
from .helpers import cid_for

CID = "bafkreidot3j5vvbthwtydmn3ny2pq2ckibhbuj5sech6wpzsxokrkqntsy"
REWARD = 3 * 10**17


def _total(chain: Chain, addresses: list[str]) -> int:
    return sum(chain.balance(a) for a in addresses)


def test_training_and_sharing_flows_conserve_payments(any_chain: Chain) -> None:
    chain = any_chain
    p = make_platform(chain)
    act = actors_of(chain)
    everyone = chain.accounts + [c.address for c in p.contracts]
    fees0 = chain.fees_paid
    total0 = _total(chain, everyone)

    p.umc.add_requester(act.requester)
    w = act.workers[:5]
    # more cores -> higher CC (Eq. 20): the ranking is w[4] > w[3] > ... > w[0]
    for i, addr in enumerate(w):
        p.umc.add_worker(addr, [DOMAIN, DOMAIN + 1], 2 + 4 * i, 32, 1)

    # -- training task: offer, decline, expiry -> next best, submit, review ------------
    tid, _ = p.tmc.add_task(
        act.requester,
        domain=DOMAIN,
        num_workers=2,
        reward=REWARD,
        duration=10 * ACCEPT_WINDOW,
        description="maze cleaning",
    )
    offered, _ = p.tmc.allocate(act.requester, tid)
    assert offered == [w[4], w[3]]
    p.tmc.transact("acceptOffer", tid, sender=w[4])
    p.tmc.transact("declineOffer", tid, sender=w[3])
    offered, _ = p.tmc.allocate(act.requester, tid)
    assert offered == [w[2]]  # next best after the decline
    chain.advance_time(ACCEPT_WINDOW + 1)
    try:
        p.tmc.transact("acceptOffer", tid, sender=w[2])
        raise AssertionError("an expired offer must not be accepted")
    except errors.get("TasksOfferExpired") as exc:
        assert exc.args_dict["worker"] == w[2]
    offered, rc = p.tmc.allocate(act.requester, tid)
    assert [e.args["worker"] for e in rc.named("OfferExpired")] == [w[2]]
    assert offered == [w[1]]
    p.tmc.transact("acceptOffer", tid, sender=w[1])
    p.tmc.submit_outcome(w[4], tid, CID)
    rc = p.tmc.submit_outcome(w[1], tid, cid_for("x"))
    assert rc.one("OutcomeSubmitted").args["cid"] == cid_for("x")
    p.tmc.transact("reviewOutcome", tid, w[4], 5, True, sender=act.requester)
    rc = p.tmc.transact("reviewOutcome", tid, w[1], 1, False, sender=act.requester)
    assert rc.one("TaskStatusUpdated").args["status"] == TaskStatus.COMPLETED
    assert p.tmc.call("credits", w[4]) == REWARD
    assert p.tmc.call("credits", act.requester) == REWARD  # rejected outcome refunded
    c = p.umc.counters(w[2], DOMAIN, 0)
    assert (c["assigned"], c["accepted"], c["completed"]) == (1, 0, 0)
    c = p.umc.counters(w[4], DOMAIN, 0)
    assert c == {"assigned": 1, "accepted": 1, "completed": 1, "rating_sum": 5, "rating_count": 1}
    c = p.umc.counters(w[1], DOMAIN, 0)  # rejected: rated, not completed
    assert c == {"assigned": 1, "accepted": 1, "completed": 0, "rating_sum": 1, "rating_count": 1}

    # -- a cancelled task and a task closed after its deadline ---------------------------
    cancel_id, _ = p.tmc.add_task(
        act.requester, domain=DOMAIN, num_workers=3, reward=REWARD, duration=10 * ACCEPT_WINDOW
    )
    p.tmc.allocate(act.requester, cancel_id)
    try:  # offered workers keep their acceptance window
        p.tmc.transact(
            "updateTaskStatus", cancel_id, int(TaskStatus.CANCELLED), sender=act.requester
        )
        raise AssertionError("cancel must wait for live offers")
    except errors.get("TasksHasLiveOffers"):
        pass
    chain.advance_time(ACCEPT_WINDOW + 1)  # nobody accepted in time
    p.tmc.transact("updateTaskStatus", cancel_id, int(TaskStatus.CANCELLED), sender=act.requester)
    assert p.tmc.task(cancel_id)["status"] == TaskStatus.CANCELLED

    p.umc.update_status(w[0], WorkerStatus.IDLE)  # w[0] gets no offer
    close_id, _ = p.tmc.add_task(
        act.requester, domain=DOMAIN + 1, num_workers=3, reward=REWARD, duration=2 * ACCEPT_WINDOW
    )
    offered, _ = p.tmc.allocate(act.requester, close_id)
    assert offered == [w[4], w[3], w[2]]
    p.tmc.transact("acceptOffer", close_id, sender=w[4])
    p.tmc.transact("acceptOffer", close_id, sender=w[3])
    p.tmc.submit_outcome(w[4], close_id, cid_for("c"))  # never reviewed
    chain.advance_time(2 * ACCEPT_WINDOW + 1)
    try:
        p.tmc.transact("updateTaskStatus", close_id, int(TaskStatus.CLOSED), sender=w[4])
        raise AssertionError("close must wait for the review window")
    except errors.get("TasksReviewWindowOpen"):
        pass
    chain.advance_time(REVIEW_WINDOW)
    rc = p.tmc.transact("updateTaskStatus", close_id, int(TaskStatus.CLOSED), sender=w[4])
    assert [e.args["worker"] for e in rc.named("OfferFailed")] == [w[3]]
    assert [e.args["worker"] for e in rc.named("OfferExpired")] == [w[2]]
    assert p.tmc.offer(close_id, w[4])["state"] == OfferState.REVIEWED
    assert p.tmc.call("credits", w[4]) == 2 * REWARD

    # -- model sharing: both metrics, reviews ----------------------------------------------
    p.umc.update_status(w[0], WorkerStatus.ACTIVE)
    m1, _ = p.mmc.add_model(w[0], cid_for("mq"), DOMAIN, [3, 3], "3A3W")
    m2, _ = p.mmc.add_model(w[1], cid_for("m2"), DOMAIN, [1, 0], "1A0W")
    m3, _ = p.mmc.add_model(w[2], cid_for("m3"), DOMAIN, [2, 2], "2A2W")
    alloc, ids, _ = p.mmc.allocate(
        act.requester, domain=DOMAIN, num_models=2, env=[3, 3], price=REWARD, metric=Metric.SHARING
    )
    assert ids == [m1, m3]  # closest environments first (Eq. 22-23)
    p.mmc.transact("updateModelRep", alloc, m1, 4, sender=act.requester)
    alloc2, ids2, _ = p.mmc.allocate(
        act.requester, domain=DOMAIN, num_models=3, env=[1, 1], price=REWARD, metric=Metric.MODEL
    )
    assert set(ids2) == {m1, m2, m3}
    for m in ids2:
        p.mmc.transact("updateModelRep", alloc2, m, 3, sender=act.requester)
    assert tuple(p.mmc.call("ownerRep", w[0])) == (2, 7)

    assert_events_rebuild_state(chain, p)

    # -- everyone withdraws: contracts end empty, nothing created or lost ------------------
    for handle in (p.tmc, p.mmc):
        for acct in chain.accounts:
            if handle.call("credits", acct):
                handle.transact("withdraw", sender=acct)
        assert chain.balance(handle.address) == 0
    assert _total(chain, everyone) + (chain.fees_paid - fees0) == total0


OFFER_EVENTS = {
    "TaskOffered": OfferState.OFFERED,
    "OfferAccepted": OfferState.ACCEPTED,
    "OfferDeclined": OfferState.DECLINED,
    "OfferExpired": OfferState.EXPIRED,
    "OfferFailed": OfferState.FAILED,
    "OutcomeSubmitted": OfferState.SUBMITTED,
    "OutcomeReviewed": OfferState.REVIEWED,
    "OutcomePaidUnreviewed": OfferState.REVIEWED,
}


def assert_events_rebuild_state(chain: Chain, p) -> None:
    """What an indexer derives from the logs alone equals the contracts' own views: task
    status, offer states, credits, worker counters and model totals."""
    tasks: dict[int, TaskStatus] = {}
    offers: dict[tuple[int, str], OfferState] = {}
    credits: dict[tuple[str, str], int] = {}
    for ev in chain.logs(p.tmc):
        a = ev.args
        if ev.name == "TaskAdded":
            tasks[a["taskId"]] = TaskStatus.OPEN
        elif ev.name == "TaskStatusUpdated":
            tasks[a["taskId"]] = TaskStatus(a["status"])
        elif ev.name in OFFER_EVENTS:
            offers[(a["taskId"], a["worker"])] = OFFER_EVENTS[ev.name]
        elif ev.name == "PaymentCredited":
            key = ("tmc", a["account"])
            credits[key] = credits.get(key, 0) + a["amount"]
    counters: dict[tuple[str, int, int], tuple[int, ...]] = {}
    for ev in chain.logs(p.umc):
        if ev.name == "WorkerInfoUpdated":
            a = ev.args
            counters[(a["worker"], a["domain"], a["taskType"])] = (
                a["assigned"],
                a["accepted"],
                a["completed"],
                a["ratingSum"],
                a["ratingCount"],
            )
    models: dict[int, list[int]] = {}
    for ev in chain.logs(p.mmc):
        a = ev.args
        if ev.name == "ModelAdded":
            models[a["modelId"]] = [0, 0]
        elif ev.name == "ModelAllocated":
            models[a["modelId"]][0] += 1
        elif ev.name == "ModelReviewed":
            models[a["modelId"]][1] += a["review"]
        elif ev.name == "PaymentCredited":
            key = ("mmc", a["account"])
            credits[key] = credits.get(key, 0) + a["amount"]
    assert tasks and offers and counters and models
    for tid, status in tasks.items():
        assert p.tmc.task(tid)["status"] == status
    for (tid, worker), state in offers.items():
        assert p.tmc.offer(tid, worker)["state"] == state
    for (which, account), amount in credits.items():
        assert getattr(p, which).call("credits", account) == amount
    for (worker, domain, ttype), values in counters.items():
        assert tuple(p.umc.counters(worker, domain, ttype).values()) == values
    for mid, (count, total) in models.items():
        assert tuple(p.mmc.call("getModel", mid)[0])[3:] == (count, total)
