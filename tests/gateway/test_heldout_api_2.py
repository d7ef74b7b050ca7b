"""Held-out probe of the gateway (second pass): sign-in timestamps UTC cannot hold, a
malformed ``Origin`` from this machine, NaN fractions, and wei amounts written as doubles. Each
used to answer a 500, an error naming the wrong rule, or a different amount than the one sent;
each is now a 4xx naming the field."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient

from .conftest import P, task_body

ADDRESS = "0x7E5F4552091A69125d5DfCb7b8C2659029395Bdf"
LOCAL = {"client": ("127.0.0.1", 50000), "base_url": "http://127.0.0.1:8000"}
ENV = {"rows": 8, "cols": 8, "agents": 2, "max_steps": 50}


def _with_line(message: str, name: str, value: str) -> str:
    return "\n".join(
        f"{name}: {value}" if line.startswith(f"{name}:") else line
        for line in message.split("\n")
    )


@pytest.mark.parametrize(
    ("line", "stamp"),
    [
        ("Issued At", "9999-12-31T23:59:59-14:00"),  # year 10000 in UTC
        ("Expiration Time", "0001-01-01T00:00:00+01:00"),  # year 0 in UTC
        ("Issued At", "2026-13-01T00:00:00Z"),  # "month must be in 1..12", of which line?
    ],
)
def test_a_sign_in_time_utc_cannot_hold_is_422_naming_its_line(client, line, stamp) -> None:
    """A timestamp whose UTC time is outside datetime's years made ``astimezone`` raise
    OverflowError in ``SiweMessage.parse``: an anonymous ``POST /auth/token`` answered 500 (and
    a worker or CLI parsing such a message from a hostile gateway crashed). Other bad
    timestamps were 422 without naming the line."""
    message = client.post(f"{P}/auth/nonce", json={"address": ADDRESS}).json()["message"]
    r = client.post(
        f"{P}/auth/token",
        json={"message": _with_line(message, line, stamp), "signature": "0x" + "11" * 65},
    )
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail["rule"] == "siwe_message_malformed" and line in detail["msg"], detail


def test_a_malformed_origin_from_this_machine_is_not_a_500(app) -> None:
    """``Origin: http://[`` (no browser sends it; any local process may) made ``urlsplit``
    raise ValueError in ``is_loopback``: every route that asks whether a request is local
    (demo users, ``/local/services``, ``/rpc``, the sign-in nonce) answered 500."""
    headers = {"Origin": "http://["}
    with TestClient(app, raise_server_exceptions=False, **LOCAL) as local:
        r = local.get(f"{P}/auth/demo-users", headers=headers)
        assert r.status_code == 404 and r.json()["detail"]["rule"] == "demo_not_local", r.text
        r = local.get(f"{P}/local/services", headers=headers)
        assert r.status_code == 404 and r.json()["detail"]["rule"] == "not_local", r.text
        r = local.post(f"{P}/auth/nonce", json={"address": ADDRESS}, headers=headers)
        assert r.status_code == 200, r.text


def test_a_nan_fraction_in_a_body_is_named_not_finite(client, login) -> None:
    """``"min_reputation": NaN`` was refused as "Input should be less than or equal to 1",
    a bound NaN does not break; now "should be a finite number" at the field."""
    h = {**login("user1"), "content-type": "application/json"}
    for url, body in (
        (f"{P}/tasks", task_body(min_reputation=float("nan"))),
        (f"{P}/models/requests", {"env": ENV, "min_rating": float("nan")}),
    ):
        r = client.post(url, content=json.dumps(body), headers=h)
        assert r.status_code == 422, r.text
        (issue,) = r.json()["detail"]
        assert issue["type"] == "finite_number" and issue["loc"][0] == "body", issue


@pytest.mark.parametrize("resource", ["workers", "models"])
def test_a_nan_fraction_in_a_query_is_named_not_finite(client, resource) -> None:
    """``?min_reputation=nan`` was refused as "less than or equal to 1" too."""
    r = client.get(f"{P}/{resource}", params={"min_reputation": "nan"})
    assert r.status_code == 422, r.text
    (issue,) = r.json()["detail"]
    assert issue["loc"] == ["query", "min_reputation"] and issue["type"] == "finite_number"


@pytest.mark.parametrize(
    ("url", "field", "body"),
    [
        (f"{P}/tasks", "payment_wei", task_body()),
        (f"{P}/models/requests", "price_wei", {"env": ENV}),
    ],
)
@pytest.mark.parametrize("raw", ["1.00000000000000001e17", "1e23", "9007199254740993.0"])
def test_wei_written_as_a_double_from_2_53_on_is_refused(
    client, login, url, field, body, raw
) -> None:
    """A wei amount with a decimal point or an exponent is read as a double:
    ``1.00000000000000001e17`` went on as 1e17 wei and ``9007199254740993.0`` as 2^53 (an
    escrow or a price other than the one written), and ``1e23`` was refused as "unable to
    parse input string as an integer" of a string nobody sent. From 2^53 on an amount of wei
    is an integer literal; the 422 names the field and says so. Below 2^53, and as a literal
    of any size, it passes on to the route's own rules (the caller is no requester: 403)."""
    text = json.dumps({k: v for k, v in body.items() if k != field})
    h = {**login("user1"), "content-type": "application/json"}
    r = client.post(url, content=text[:-1] + f', "{field}": {raw}}}', headers=h)
    assert r.status_code == 422, r.text
    (issue,) = r.json()["detail"]
    assert issue["loc"] == ["body", field] and "integer (digits only)" in issue["msg"], issue
    for fine in ("1e15", "1000000000000000000000"):
        r = client.post(url, content=text[:-1] + f', "{field}": {fine}}}', headers=h)
        assert r.status_code == 403 and "not_requester" in r.json()["detail"]["rule"], r.text

