"""Sign-in over HTTP with real eth_account keys, and every rule that must refuse a request."""

from __future__ import annotations

import datetime as dt
import re
from collections.abc import Iterator
from pathlib import Path

import jwt
import pytest
from eth_account import Account
from eth_account.messages import encode_defunct
from fastapi import APIRouter
from fastapi.testclient import TestClient

from backend.api.deps import CurrentUser
from backend.api.main import API_PREFIX, create_app
from backend.api.schemas import Address
from backend.auth import DemoKeys, bearer_headers, issue_token, require_self
from backend.db.models import AuthNonce
from backend.errors import Unauthorized
from backend.settings import Settings, load_settings

from .conftest import Clock

P = API_PREFIX

# A route acting on behalf of an address, as resource routers will: only the signer may.
_acting = APIRouter()


@_acting.put("/acting-as/{address}")
def _act(address: Address, user: CurrentUser) -> dict[str, str]:
    return {"acted_as": require_self(user, address)}


@pytest.fixture
def client(settings: Settings, clock: Clock) -> Iterator[TestClient]:
    app = create_app(settings, clock=clock)
    app.include_router(_acting, prefix=P)
    with TestClient(app) as c:
        yield c


def sign(account, text: str) -> str:
    return "0x" + bytes(account.sign_message(encode_defunct(text=text)).signature).hex()


def get_message(client: TestClient, address: str) -> str:
    r = client.post(f"{P}/auth/nonce", json={"address": address})
    assert r.status_code == 200, r.text
    return r.json()["message"]


def exchange(client: TestClient, message: str, signature: str):
    return client.post(f"{P}/auth/token", json={"message": message, "signature": signature})


def assert_rule(r, status: int, rule: str) -> None:
    assert r.status_code == status, r.text
    body = r.json()
    assert set(body) == {"detail"} and set(body["detail"]) == {"rule", "msg"}, body
    assert body["detail"]["rule"] == rule, body
    assert body["detail"]["msg"]


def test_sign_in_flow_gives_a_token_bound_to_the_signer(
    client: TestClient, keys: DemoKeys, settings: Settings
) -> None:
    alice = keys.account("alice")
    r = client.post(f"{P}/auth/nonce", json={"address": alice.address.lower()})
    assert r.status_code == 200
    body = r.json()
    msg = body["message"]
    # EIP-4361 layout, with the gateway's domain, the embedded chain id and a checksummed address
    assert msg.startswith(
        f"{settings.auth_domain} wants you to sign in with your Ethereum account:\n"
    )
    assert f"\n{alice.address}\n" in msg
    assert f"\nChain ID: {settings.effective_chain_id}\n" in msg
    assert f"\nNonce: {body['nonce']}\n" in msg
    assert re.search(r"\nIssued At: \d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ\n", msg)
    with client.app.state.sessions() as s:
        row = s.get(AuthNonce, body["nonce"])
        assert row.address == alice.address and row.used_at is None

    r = exchange(client, msg, sign(alice, msg))
    assert r.status_code == 200, r.text
    tok = r.json()
    assert tok["address"] == alice.address and tok["token_type"] == "bearer"
    me = client.get(f"{P}/auth/me", headers=bearer_headers(tok["access_token"]))
    assert me.status_code == 200 and me.json() == {"address": alice.address}
    with client.app.state.sessions() as s:
        assert s.get(AuthNonce, body["nonce"]).used_at is not None

    claims = jwt.decode(tok["access_token"], options={"verify_signature": False})
    assert claims["exp"] - claims["iat"] == settings.token_ttl_s


def test_nonces_are_unique(client: TestClient, keys: DemoKeys) -> None:
    nonces = {
        client.post(f"{P}/auth/nonce", json={"address": keys.address("alice")}).json()["nonce"]
        for _ in range(5)
    }
    assert len(nonces) == 5


def test_replayed_nonce_is_refused(client: TestClient, keys: DemoKeys) -> None:
    alice = keys.account("alice")
    msg = get_message(client, alice.address)
    sig = sign(alice, msg)
    assert exchange(client, msg, sig).status_code == 200
    assert_rule(exchange(client, msg, sig), 401, "siwe_nonce_used")


def test_expired_message_is_refused(
    client: TestClient, keys: DemoKeys, clock: Clock, settings: Settings
) -> None:
    alice = keys.account("alice")
    msg = get_message(client, alice.address)
    clock.advance(settings.nonce_ttl_s - 1)
    fresh = get_message(client, alice.address)
    assert exchange(client, fresh, sign(alice, fresh)).status_code == 200
    clock.advance(2)  # now past the first message's expiry
    r = exchange(client, msg, sign(alice, msg))
    assert_rule(r, 401, "siwe_expired")


@pytest.mark.parametrize(
    ("pattern", "replacement", "rule"),
    [
        (r"^\S+ wants", "evil.example wants", "siwe_domain_mismatch"),
        (r"Chain ID: \d+", "Chain ID: 1", "siwe_chain_mismatch"),
        (r"Nonce: \w+", "Nonce: 00000000deadbeef", "siwe_nonce_unknown"),
        (r"Version: 1", "Version: 2", "siwe_version"),
        # the fields the gateway wrote: the signed text must be the one issued
        (r"^Sign in.*$", "I transfer all my funds.", "siwe_message_altered"),
        (r"^URI: .*$", "URI: javascript:alert(1)", "siwe_message_altered"),
        (r"^Issued At: .*$", "Issued At: 2999-01-01T00:00:00Z", "siwe_message_altered"),
        (r"^Expiration Time: .*$", "Expiration Time: 2999-01-01T00:00:00Z", "siwe_message_altered"),
        (r"\Z", "\x00", "siwe_message_altered"),
    ],
)
def test_altered_message_signed_by_the_owner_is_refused(
    client: TestClient, keys: DemoKeys, pattern: str, replacement: str, rule: str
) -> None:
    """The signature is valid for the altered text: the field checks alone must refuse it."""
    alice = keys.account("alice")
    msg = re.sub(pattern, replacement, get_message(client, alice.address), count=1, flags=re.M)
    assert_rule(exchange(client, msg, sign(alice, msg)), 401, rule)


def test_message_signed_by_someone_else_is_refused(client: TestClient, keys: DemoKeys) -> None:
    msg = get_message(client, keys.address("alice"))
    assert_rule(
        exchange(client, msg, sign(keys.account("bob"), msg)), 401, "siwe_signature_mismatch"
    )


def test_nonce_issued_to_another_address_is_refused(client: TestClient, keys: DemoKeys) -> None:
    """Bob swaps his address into Alice's message and signs it himself."""
    alice, bob = keys.account("alice"), keys.account("bob")
    msg = get_message(client, alice.address).replace(alice.address, bob.address)
    assert_rule(exchange(client, msg, sign(bob, msg)), 401, "siwe_nonce_address")


@pytest.mark.parametrize("sig", ["00" * 64 + "1b", "ff" * 65])
def test_unrecoverable_signature_is_refused(client: TestClient, keys: DemoKeys, sig: str):
    msg = get_message(client, keys.address("alice"))
    assert_rule(exchange(client, msg, "0x" + sig), 401, "siwe_signature_invalid")


def test_malformed_message_is_refused(client: TestClient, keys: DemoKeys) -> None:
    text = "please let me in"
    assert_rule(
        exchange(client, text, sign(keys.account("alice"), text)), 422, "siwe_message_malformed"
    )


def test_validation_errors_name_the_field(client: TestClient) -> None:
    r = client.post(f"{P}/auth/nonce", json={"address": "0x" + "g" * 40})
    assert r.status_code == 422
    (issue,) = r.json()["detail"]
    assert issue["loc"] == ["body", "address"] and set(issue) == {"loc", "msg", "type"}
    r = client.post(f"{P}/auth/token", json={"message": "x", "signature": "0x12"})
    assert r.status_code == 422
    assert [i["loc"] for i in r.json()["detail"]] == [["body", "signature"]]
    r = client.post(f"{P}/auth/token", json={})
    assert sorted(i["loc"][-1] for i in r.json()["detail"]) == ["message", "signature"]


# -- tokens -------------------------------------------------------------------------------------
def test_missing_or_non_bearer_authorization_is_refused(client: TestClient) -> None:
    r = client.get(f"{P}/auth/me")
    assert_rule(r, 401, "auth_required")
    assert r.headers["www-authenticate"].startswith("Bearer")
    assert_rule(
        client.get(f"{P}/auth/me", headers={"Authorization": "Basic YTpi"}), 401, "auth_required"
    )


def test_expired_token_is_refused(client: TestClient, keys: DemoKeys, settings: Settings) -> None:
    past = dt.datetime.now(dt.UTC) - dt.timedelta(seconds=settings.token_ttl_s + 5)
    old = issue_token(keys.address("alice"), settings=settings, now=past).access_token
    assert_rule(client.get(f"{P}/auth/me", headers=bearer_headers(old)), 401, "token_expired")


def test_forged_tokens_are_refused(
    client: TestClient, keys: DemoKeys, settings: Settings, tmp_path: Path
) -> None:
    alice, bob = keys.address("alice"), keys.address("bob")
    # signed with another secret (e.g. another deployment)
    other = load_settings(data_dir=tmp_path / "other")
    forged = issue_token(bob, settings=other).access_token
    assert_rule(client.get(f"{P}/auth/me", headers=bearer_headers(forged)), 401, "token_invalid")
    # a real token for alice with the payload rewritten to bob (signature no longer matches)
    real = issue_token(alice, settings=settings).access_token
    head, _, sig = real.split(".")
    claims = jwt.decode(real, options={"verify_signature": False})
    claims["sub"] = bob
    body = jwt.encode(claims, "k" * 32, algorithm="HS256").split(".")[1]
    tampered = f"{head}.{body}.{sig}"
    assert_rule(client.get(f"{P}/auth/me", headers=bearer_headers(tampered)), 401, "token_invalid")
    # unsigned ("alg": "none")
    unsigned = jwt.encode(claims, None, algorithm="none")
    assert_rule(client.get(f"{P}/auth/me", headers=bearer_headers(unsigned)), 401, "token_invalid")
    assert_rule(
        client.get(f"{P}/auth/me", headers=bearer_headers("not.a.jwt")), 401, "token_invalid"
    )


def test_a_request_can_only_act_as_the_signer(client: TestClient, keys: DemoKeys) -> None:
    token = keys.sign_in(client, "alice")
    alice, bob = keys.address("alice"), keys.address("bob")
    r = client.put(f"{P}/acting-as/{alice.lower()}", headers=bearer_headers(token))
    assert r.status_code == 200 and r.json() == {"acted_as": alice}
    assert_rule(
        client.put(f"{P}/acting-as/{bob}", headers=bearer_headers(token)), 403, "act_as_self_only"
    )
    assert_rule(client.put(f"{P}/acting-as/{alice}"), 401, "auth_required")


def test_demo_keys_are_refused_in_production(tmp_path: Path) -> None:
    prod = load_settings(
        mode="production", token_secret=Account.create().key.hex(), data_dir=tmp_path
    )
    with pytest.raises(RuntimeError, match="production"):
        DemoKeys(prod)


def test_demo_keys_sign_like_the_user(keys: DemoKeys) -> None:
    text = "hello"
    sig = keys.sign("alice", text)
    assert Account.recover_message(encode_defunct(text=text), signature=sig) == keys.address(
        "alice"
    )
    with pytest.raises(KeyError, match="carol"):
        keys.address("carol")


def test_unknown_chain_id_is_a_503_rule(tmp_path: Path, keys: DemoKeys) -> None:
    """Against a JSON-RPC chain the id comes from the node; until then sign-in says so."""
    s = load_settings(data_dir=tmp_path, chain="http://127.0.0.1:1")
    with TestClient(create_app(s)) as c:
        assert_rule(
            c.post(f"{P}/auth/nonce", json={"address": keys.address("alice")}),
            503,
            "chain_id_unknown",
        )


def test_nonce_consumed_by_a_concurrent_request_is_refused(
    client: TestClient, keys: DemoKeys, settings: Settings, clock: Clock
) -> None:
    """Two requests with one nonce: the loser read the row before the winner consumed it; the
    conditional UPDATE (not the stale read) must refuse it."""
    from backend.auth import verify_sign_in

    alice = keys.account("alice")
    r = client.post(f"{P}/auth/nonce", json={"address": alice.address})
    msg, nonce = r.json()["message"], r.json()["nonce"]
    sessions = client.app.state.sessions
    with sessions() as loser, sessions() as winner:
        assert loser.get(AuthNonce, nonce).used_at is None  # stale copy in the identity map
        kwargs = dict(
            message=msg,
            signature=sign(alice, msg),
            settings=settings,
            chain_id=settings.effective_chain_id,
            now=clock(),
        )
        assert verify_sign_in(winner, **kwargs) == alice.address
        with pytest.raises(Unauthorized) as err:
            verify_sign_in(loser, **kwargs)
    assert err.value.rule == "siwe_nonce_used"


def test_sign_in_messages_are_rate_limited_per_remote_client(
    settings: Settings, clock: Clock, keys: DemoKeys
) -> None:
    """Each message is a row until it expires: one client must not fill the table."""
    limited = settings.model_copy(update={"auth_nonces_per_minute": 3})
    app = create_app(limited, clock=clock)
    body = {"address": keys.address("alice")}
    with TestClient(app, client=("198.51.100.7", 4000)) as remote:
        codes = [remote.post(f"{P}/auth/nonce", json=body).status_code for _ in range(3)]
        assert codes == [200] * 3
        r = remote.post(f"{P}/auth/nonce", json=body)
        assert_rule(r, 429, "auth_rate_limited")
        assert 1 <= int(r.headers["Retry-After"]) <= 60
    with TestClient(app, client=("198.51.100.8", 4000)) as other:  # another client: its own
        assert other.post(f"{P}/auth/nonce", json=body).status_code == 200
    local_url = "http://127.0.0.1:8000"  # a loopback peer whose Host is this machine too
    with TestClient(app, client=("127.0.0.1", 4000), base_url=local_url) as local:  # unmetered
        assert all(local.post(f"{P}/auth/nonce", json=body).status_code == 200 for _ in range(5))
