"""``POST /api/chain/faucet``: only on the embedded demo chain, and rate-limited per address and
overall (429 + Retry-After naming the limit)."""

from __future__ import annotations

from pathlib import Path

import pytest
from eth_account import Account
from eth_account.messages import encode_defunct
from eth_account.signers.local import LocalAccount
from fastapi.testclient import TestClient

from backend.api.main import create_app
from backend.services.chain import ChainService
from backend.services.faucet import FAUCET_THRESHOLD_WEI, FAUCET_WEI, Faucet, FaucetLimited
from backend.settings import Settings

URL = "/api/chain/faucet"


def sign_in(client: TestClient, account: LocalAccount) -> dict[str, str]:
    """The EIP-4361 flow with the caller's own key (works in production mode too)."""
    r = client.post("/api/auth/nonce", json={"address": account.address})
    assert r.status_code == 200, r.text
    message = r.json()["message"]
    signature = account.sign_message(encode_defunct(text=message)).signature
    r = client.post(
        "/api/auth/token", json={"message": message, "signature": "0x" + bytes(signature).hex()}
    )
    assert r.status_code == 200, r.text
    return {"Authorization": f"Bearer {r.json()['access_token']}"}


def spend(service: ChainService, account: LocalAccount, wei: int) -> None:
    """``account`` sends ``wei`` away with its own signed transaction."""
    w3 = service.chain.w3
    with service.lock:
        base = w3.eth.get_block("latest")["baseFeePerGas"]
        tx = {
            "to": service.chain.accounts[1],
            "value": wei,
            "gas": 21_000,
            "chainId": service.chain.chain_id,
            "nonce": w3.eth.get_transaction_count(account.address),
            "maxFeePerGas": 2 * base,
            "maxPriorityFeePerGas": 0,
        }
        sent = w3.eth.send_raw_transaction(account.sign_transaction(tx).raw_transaction)
        w3.eth.wait_for_transaction_receipt(sent)


def make_client(settings: Settings, service: ChainService) -> TestClient:
    return TestClient(create_app(settings, chain=service, indexer_interval=None))


def test_top_up_once_then_nothing_while_funded(settings: Settings, service: ChainService) -> None:
    me = Account.create()
    with make_client(settings, service) as c:
        headers = sign_in(c, me)
        first = c.post(URL, headers=headers)
        again = c.post(URL, headers=headers)
    assert first.status_code == 200, first.text
    body = first.json()
    assert body["address"] == me.address and body["tx_hash"]
    assert int(body["balance_wei"]) == FAUCET_WEI == service.chain.balance(me.address)
    receipt = service.chain.w3.eth.get_transaction_receipt(body["tx_hash"])
    assert receipt["status"] == 1 and receipt["to"] == me.address
    # funded: answered without a transfer, and not counted against the rate limit
    assert again.status_code == 200
    assert again.json() == {**body, "tx_hash": None}


def test_one_top_up_per_address_per_interval(tmp_path: Path, service: ChainService) -> None:
    settings = Settings(data_dir=tmp_path / "d", faucet_interval_s=600)
    me = Account.create()
    with make_client(settings, service) as c:
        headers = sign_in(c, me)
        assert c.post(URL, headers=headers).status_code == 200
        spend(service, me, FAUCET_WEI - FAUCET_THRESHOLD_WEI // 2)  # below the threshold again
        r = c.post(URL, headers=headers)
    assert r.status_code == 429
    assert r.json()["detail"]["rule"] == "faucet_address_rate"
    assert 1 <= int(r.headers["Retry-After"]) <= 600
    assert service.chain.balance(me.address) < FAUCET_THRESHOLD_WEI  # nothing was sent


def test_top_ups_per_minute_over_all_addresses(tmp_path: Path, service: ChainService) -> None:
    settings = Settings(data_dir=tmp_path / "d", faucet_per_minute=2)
    people = [Account.create() for _ in range(3)]
    with make_client(settings, service) as c:
        answers = [c.post(URL, headers=sign_in(c, p)) for p in people]
    assert [a.status_code for a in answers] == [200, 200, 429]
    assert answers[2].json()["detail"]["rule"] == "faucet_global_rate"
    assert 1 <= int(answers[2].headers["Retry-After"]) <= 60
    assert service.chain.balance(people[2].address) == 0


def test_limits_lift_after_their_windows(service: ChainService) -> None:
    """The same limits on a clock the test moves: the address may come back after the
    interval, everyone after the minute."""
    now = [1000.0]
    faucet = Faucet(service, interval_s=30, per_minute=1, clock=lambda: now[0])
    a, b = Account.create(), Account.create()
    assert faucet.top_up(a.address).tx_hash is not None
    with pytest.raises(FaucetLimited) as err:
        faucet.top_up(b.address)
    assert (err.value.rule, err.value.retry_after) == ("faucet_global_rate", 60)
    now[0] += 59.5
    with pytest.raises(FaucetLimited) as err:
        faucet.top_up(b.address)
    assert err.value.retry_after == 1
    now[0] += 0.5
    assert faucet.top_up(b.address).tx_hash is not None
    spend(service, a, FAUCET_WEI - FAUCET_THRESHOLD_WEI // 2)
    now[0] += 60  # past the minute and a's 30 s interval
    assert faucet.top_up(a.address).tx_hash is not None
    spend(service, a, FAUCET_WEI)
    with pytest.raises(FaucetLimited) as err:  # both limits hit: the address one is named
        faucet.top_up(a.address)
    assert err.value.rule == "faucet_address_rate" and err.value.retry_after == 30


def test_no_faucet_outside_the_embedded_demo_mode(tmp_path: Path, service: ChainService) -> None:
    production = Settings(data_dir=tmp_path / "p", mode="production", token_secret="k" * 40)
    me = Account.create()
    with make_client(production, service) as c:
        r = c.post(URL, headers=sign_in(c, me))
    assert r.status_code == 404
    assert r.json()["detail"]["rule"] == "faucet_disabled"
    assert service.chain.balance(me.address) == 0
