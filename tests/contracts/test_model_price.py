"""Issue 8, finding 4: no free model allocations.

Every allocation counts in Eq. 10 and Eq. 11, so with msg.value = 0 anyone could drive any
model's and owner's reputation to 0 for free. An allocation now pays every allocated model's
owner at least the admin-set minModelPrice (1 wei when none is set)."""

from __future__ import annotations

import pytest

from backend.chain import qos
from backend.chain.platform import Metric

from .conftest import DOMAIN
from .helpers import CID, reverts

PRICE = 10**12


@pytest.fixture
def setup(p, actors):
    p.umc.add_requester(actors.requester)
    w = actors.workers[0]
    p.umc.add_worker(w, [DOMAIN], 4, 16, 1)
    mid, _ = p.mmc.add_model(w, CID, DOMAIN, [2, 2])
    return p, actors.requester, w, mid


@pytest.mark.parametrize("metric", [Metric.MODEL, Metric.SHARING])
def test_free_allocations_are_refused(setup, metric) -> None:
    """The attack: allocate a model for nothing, never review it: Eq. 11 falls to 0."""
    p, r, w, mid = setup
    err = reverts(
        "ModelsPriceBelowMinimum",
        p.mmc.allocate,
        r,
        domain=DOMAIN,
        num_models=1,
        env=[2, 2],
        price=0,
        metric=metric,
    )
    assert err.args_dict == {"price": 0, "minimum": 1}
    model = p.mmc.call("getModel", mid)[0]
    assert (model[3], model[4]) == (0, 0)  # allocCount, totalReview: untouched
    assert p.mmc.call("credits", w) == 0


def test_minimum_price_is_an_admin_setting(setup, actors) -> None:
    p, r, w, mid = setup
    assert p.mmc.call("minModelPrice") == 1
    for who in (r, w, actors.outsider):
        err = reverts("ModelsNotAdmin", p.mmc.set_min_model_price, who, PRICE)
        assert err.args_dict == {"account": who}
    rc = p.mmc.set_min_model_price(actors.admin, PRICE)
    assert rc.one("MinModelPriceUpdated").args["weiPerModel"] == PRICE
    reverts("ModelsBadConfig", p.mmc.set_min_model_price, actors.admin, 0)
    reverts("ModelsBadConfig", p.mmc.set_min_model_price, actors.admin, 2**80)
    err = reverts(
        "ModelsPriceBelowMinimum",
        p.mmc.allocate,
        r,
        domain=DOMAIN,
        num_models=2,
        env=[2, 2],
        price=PRICE - 1,
    )
    assert err.args_dict == {"price": PRICE - 1, "minimum": PRICE}


def test_every_allocation_that_counts_against_a_model_pays_its_owner(setup, actors) -> None:
    """Lowering a model's reputation now costs the minimum price per allocation, paid to
    the owner: after k unreviewed allocations the owner holds k prices."""
    p, r, w, mid = setup
    p.mmc.set_min_model_price(actors.admin, PRICE)
    k = 3
    for _ in range(k):
        p.mmc.allocate(r, domain=DOMAIN, num_models=1, env=[2, 2], price=PRICE, metric=Metric.MODEL)
    model = p.mmc.call("getModel", mid)[0]
    assert model[3] == k and qos.rating_fixed(model[4], model[3]) == 0
    assert p.mmc.call("credits", w) == k * PRICE
