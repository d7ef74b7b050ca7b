"""Held-out probe of the gateway (third pass): integer fields given huge JSON numbers, and
listing another worker's outcome. The first was refused with a message about a string nobody
sent; the second read up to 64 MiB from the store before the chain's rule refused it."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient

from backend.api.routes import models as model_routes
from backend.services.chain import ChainService
from backend.store.bundle import add_bundle

from .conftest import ENV, Login, P, addr, register, task_body
from .test_models import card_of, weights_of


@pytest.mark.parametrize("raw", ["1e20", "1e308", "-1e300"])
@pytest.mark.parametrize(
    ("url", "field", "body"),
    [
        (f"{P}/tasks", "num_workers", task_body()),
        (f"{P}/tasks", "domain", task_body()),
        (f"{P}/models/requests", "num_models", {"env": ENV}),
    ],
)
def test_an_integer_field_given_a_huge_number_says_so(
    client: TestClient, login: Login, url: str, field: str, body: dict, raw: str
) -> None:
    """``"num_workers": 1e20`` was refused as "Unable to parse input string as an integer,
    exceeded maximum size": the caller sent a number, not a string. Now the 422 names the field
    and says the number is beyond its bounds."""
    text = json.dumps({k: v for k, v in body.items() if k != field})
    h = {**login("user1"), "content-type": "application/json"}
    r = client.post(url, content=text[:-1] + f', "{field}": {raw}}}', headers=h)
    assert r.status_code == 422, r.text
    (issue,) = r.json()["detail"]
    assert issue["loc"] == ["body", field], issue
    assert "string" not in issue["msg"] and "beyond" in issue["msg"], issue


def test_a_query_integer_of_many_digits_keeps_pydantics_message(client: TestClient) -> None:
    """A query parameter is a string: there pydantic's "input string" is the right words."""
    r = client.get(f"{P}/models", params={"domain": "9" * 5000})
    assert r.status_code == 422, r.text
    (issue,) = r.json()["detail"]
    assert issue["loc"] == ["query", "domain"], issue
    assert "input string" in issue["msg"] and "beyond" not in issue["msg"], issue


def test_listing_another_workers_outcome_is_refused_before_the_store_is_read(
    client: TestClient, login: Login, service: ChainService, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Anyone registered could name another worker's outcome in ``POST /models``: the gateway
    fetched its card and up to 64 MiB of weights (``_check_bundle``) before ``addModel``
    reverted with the MMC's provenance rule. Now the rule is asked first (403, and 409 for
    the outcome's own worker before the requester accepts it), with no store read."""
    register(client, login, ["user1"], {"user3": {"cpu_cores": 16}, "user4": {"cpu_cores": 8}})
    r = client.post(f"{P}/tasks", json=task_body(num_workers=2), headers=login("user1"))
    assert r.status_code == 201, r.text
    task_id, offered = r.json()["task_id"], r.json()["offered"]
    names = {addr(service, n): n for n in ("user3", "user4")}
    owner, other = offered[0], offered[1]
    store = client.app.state.store  # type: ignore[attr-defined]
    cid = add_bundle(store, {"model.safetensors": weights_of("trained", 500),
                             "model.json": card_of(ENV, "o")})
    with service.lock:
        for w in offered:
            service.platform.tmc.transact("acceptOffer", task_id, sender=w)
        service.platform.tmc.submit_outcome(owner, task_id, cid)

    def store_read(*_: object) -> None:
        raise AssertionError("the store was read before the chain's rule")

    for check in ("_check_card_env", "_check_published", "_check_bundle"):
        monkeypatch.setattr(model_routes, check, store_read)
    share = {"cid": cid, "env": ENV, "description": "not mine"}
    r = client.post(f"{P}/models", json=share, headers=login(names[other]))
    assert r.status_code == 403, r.text
    detail = r.json()["detail"]
    assert detail["rule"] == "models_not_outcome_owner" and str(task_id) in detail["msg"]
    r = client.post(f"{P}/models", json=share, headers=login(names[owner]))
    assert r.status_code == 409 and r.json()["detail"]["rule"] == "models_outcome_not_accepted"
    assert "pending" in r.json()["detail"]["msg"], r.text
