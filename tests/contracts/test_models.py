"""MMC (Models Manager): models, allocation (both metrics), reviews, payments."""

from __future__ import annotations

import pytest

from backend.chain import qos
from backend.chain.platform import Metric

from .conftest import DOMAIN
from .helpers import CID, cid_for, reverts

PRICE = 10**15


@pytest.fixture
def setup(p, actors):
    p.umc.add_requester(actors.requester)
    ws = actors.workers[:3]
    for w in ws:
        p.umc.add_worker(w, [DOMAIN], 4, 16, 1)
    return p, actors.requester, ws


def test_add_model_stores_and_validates(setup, actors) -> None:
    p, _, ws = setup
    mid, rc = p.mmc.add_model(ws[0], CID, DOMAIN, [3, 1, 2], "3 agents, 1 target, 2 walls")
    ev = rc.one("ModelAdded").args
    assert (ev["cid"], ev["env"], ev["description"]) == (
        CID,
        [3, 1, 2],
        "3 agents, 1 target, 2 walls",
    )
    (owner, domain, env_len, count, total), cid, env = p.mmc.call("getModel", mid)
    assert (owner, domain, env_len, count, total, cid, env) == (
        ws[0],
        DOMAIN,
        3,
        0,
        0,
        CID,
        [3, 1, 2],
    )
    assert p.mmc.call("domainModels", DOMAIN) == [mid]
    reverts("ModelsNotWorker", p.mmc.add_model, actors.requester, CID, DOMAIN, [1])
    reverts("ModelsBadDomain", p.mmc.add_model, ws[0], CID, 256, [1])
    reverts("ModelsEmptyCid", p.mmc.add_model, ws[0], "", DOMAIN, [1])
    reverts("ModelsBadEnv", p.mmc.add_model, ws[0], CID, DOMAIN, [1] * (qos.MAX_ENV_DIMS + 1))


def test_allocate_pays_owners_refunds_rest(setup) -> None:
    p, r, ws = setup
    m1, _ = p.mmc.add_model(ws[0], cid_for("q"), DOMAIN, [2, 2])
    m2, _ = p.mmc.add_model(ws[1], cid_for("2"), DOMAIN, [5, 5])
    p.mmc.add_model(ws[2], cid_for("3"), DOMAIN, [1, 1, 1])  # other attribute count: never eligible
    alloc, ids, rc = p.mmc.allocate(
        r,
        domain=DOMAIN,
        num_models=4,
        env=[2, 3],
        price=PRICE,
        metric=Metric.MODEL,
        weights=[750_000, 250_000],
    )
    assert ids == [m1, m2]
    qos = [e.args["qos"] for e in rc.named("ModelAllocated")]
    # Eq. 12-13 with new owners and models at 0.5: 0.25 / (1 + D); D(m1) = 0.25, D(m2) = 2.75
    assert qos == [250_000 * 10**6 // 1_250_000, 250_000 * 10**6 // 3_750_000]
    assert p.mmc.call("credits", ws[0]) == PRICE and p.mmc.call("credits", ws[1]) == PRICE
    assert p.mmc.call("credits", r) == 2 * PRICE  # two unfilled slots refunded
    assert p.mmc.call("getAllocation", alloc)[0] == r
    assert p.umc.counters(ws[0], DOMAIN, 1)["completed"] == 1


def test_allocate_reverts(setup, actors) -> None:
    p, r, ws = setup
    p.mmc.add_model(ws[0], CID, DOMAIN, [2, 2])
    base = {"domain": DOMAIN, "num_models": 1, "env": [2, 2]}

    def alloc(**o):
        return p.mmc.allocate(r, **(base | o))

    reverts("ModelsBadModelCount", alloc, num_models=0)
    reverts("ModelsBadModelCount", alloc, num_models=17)
    reverts("ModelsBadDomain", alloc, domain=256)
    reverts("ModelsBadThreshold", alloc, min_reputation=10**6 + 1)
    reverts("ModelsBadThreshold", alloc, min_rating=10**6 + 1)
    reverts("ModelsBadThreshold", alloc, min_model_reputation=10**6 + 1)
    reverts("ModelsBadWeights", alloc, weights=[10**6])
    reverts("ModelsBadWeights", alloc, weights=[10**6, 1])
    reverts("ModelsBadEnv", alloc, env=[0] * (qos.MAX_ENV_DIMS + 1))
    reverts("ModelsNoEligibleModel", alloc, env=[1])
    reverts("ModelsNoEligibleModel", alloc, min_reputation=600_000)  # new owner: 0.5
    reverts(
        "ModelsBadPayment",
        p.mmc.transact,
        "allocateModel",
        (DOMAIN, 2, 0, 0, 0, 0, [2, 2], []),
        sender=r,
        value=3,
    )
    reverts("ModelsNotRequester", p.mmc.allocate, actors.outsider, **base)


def test_review_once_updates_reputations(setup) -> None:
    p, r, ws = setup
    m1, _ = p.mmc.add_model(ws[0], CID, DOMAIN, [2, 2])
    alloc, ids, _ = p.mmc.allocate(r, domain=DOMAIN, num_models=1, env=[2, 2], price=PRICE)
    reverts("ModelsBadReview", p.mmc.transact, "updateModelRep", alloc, m1, 6, sender=r)
    reverts("ModelsNotAllocated", p.mmc.transact, "updateModelRep", alloc, m1 + 1, 5, sender=r)
    rc = p.mmc.transact("updateModelRep", alloc, m1, 4, sender=r)
    assert rc.one("ModelReviewed").args == {"allocId": alloc, "modelId": m1, "review": 4}
    assert tuple(p.mmc.call("getModel", m1)[0][3:]) == (1, 4)
    assert tuple(p.mmc.call("ownerRep", ws[0])) == (1, 4)
    assert p.umc.counters(ws[0], DOMAIN, 1)["rating_sum"] == 4
    reverts("ModelsNotAllocated", p.mmc.transact, "updateModelRep", alloc, m1, 4, sender=r)
    reverts(
        "ModelsNotAllocationRequester", p.mmc.transact, "updateModelRep", alloc + 1, m1, 4, sender=r
    )
    before = p.chain.balance(ws[0])
    rc = p.mmc.transact("withdraw", sender=ws[0])
    assert p.chain.balance(ws[0]) - before == PRICE - rc.fee


def test_requester_never_gets_its_own_model(setup) -> None:
    p, r, ws = setup
    p.umc.add_worker(r, [DOMAIN], 4, 16, 1)
    p.mmc.add_model(r, cid_for("r"), DOMAIN, [2, 2])  # identical environment: would rank first
    other, _ = p.mmc.add_model(ws[0], cid_for("w"), DOMAIN, [9, 9])
    for metric in (Metric.SHARING, Metric.MODEL):
        _, ids, _ = p.mmc.allocate(r, domain=DOMAIN, num_models=2, env=[2, 2], metric=metric)
        assert ids == [other]
