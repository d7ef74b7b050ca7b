"""Issue 8, finding 3: one model is never sold twice in one allocation.

The attack: one owner listed one CID several times and filled every slot of a request with
it, paid once per slot. A CID is now listed once (issue 7) and an allocation holds each
model id at most once, so a lone model fills one slot and the others are refunded."""

from __future__ import annotations

import pytest

from backend.chain.platform import Metric

from .conftest import DOMAIN
from .helpers import CID, cid_for, reverts

PRICE = 10**12


@pytest.fixture
def setup(p, actors):
    p.umc.add_requester(actors.requester)
    ws = actors.workers[:2]
    for w in ws:
        p.umc.add_worker(w, [DOMAIN], 4, 16, 1)
    return p, actors.requester, ws


def test_a_cid_is_listed_once_by_anyone(setup) -> None:
    p, _, ws = setup
    mid, _ = p.mmc.add_model(ws[0], CID, DOMAIN, [2, 2])
    for owner in ws:  # the same owner again, or another one
        err = reverts("ModelsDuplicateModel", p.mmc.add_model, owner, CID, DOMAIN, [2, 2])
        assert err.args_dict == {"modelId": mid}
    assert p.mmc.call("domainModels", DOMAIN) == [mid]


@pytest.mark.parametrize("metric", [Metric.MODEL, Metric.SHARING])
def test_a_lone_model_fills_one_slot_and_is_paid_once(setup, metric) -> None:
    p, r, ws = setup
    mid, _ = p.mmc.add_model(ws[0], CID, DOMAIN, [2, 2])
    _, ids, rc = p.mmc.allocate(
        r, domain=DOMAIN, num_models=3, env=[2, 2], price=PRICE, metric=metric
    )
    assert ids == [mid]
    assert p.mmc.call("credits", ws[0]) == PRICE
    assert p.mmc.call("credits", r) == 2 * PRICE  # the two unfilled slots
    assert p.mmc.call("getModel", mid)[0][3] == 1  # counted once in Eq. 11


@pytest.mark.parametrize("metric", [Metric.MODEL, Metric.SHARING])
def test_allocations_never_repeat_a_model(setup, metric) -> None:
    """Several models of one owner and one of another, more slots than models: every id once."""
    p, r, ws = setup
    mine = [p.mmc.add_model(ws[0], cid_for(c), DOMAIN, [2, 2])[0] for c in "abc"]
    theirs, _ = p.mmc.add_model(ws[1], cid_for("z"), DOMAIN, [2, 3])
    _, ids, _ = p.mmc.allocate(
        r, domain=DOMAIN, num_models=8, env=[2, 2], price=PRICE, metric=metric
    )
    assert sorted(ids) == sorted([*mine, theirs])
    assert p.mmc.call("credits", ws[0]) == 3 * PRICE and p.mmc.call("credits", ws[1]) == PRICE
