"""Gas for a new key (``workers.daemon.funding.ensure_gas``, used by the CLI's writes and
``drlaas worker run``): the embedded demo chain's faucet funds an empty key once; where the
faucet refuses, the error names the address and what to do."""

from __future__ import annotations

from pathlib import Path

import pytest
from eth_account import Account
from fastapi.testclient import TestClient

from backend.api.main import create_app
from backend.services.chain import ChainService
from backend.settings import Settings
from workers.daemon.funding import NoGas, chain_balance, ensure_gas
from workers.daemon.gateway import Gateway


def test_an_empty_key_is_funded_once(
    client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the test client is http://testserver; the gateway signs in as its default localhost:8000
    monkeypatch.setenv("DRLAAS_AUTH_DOMAIN", client.app.state.settings.auth_domain)
    monkeypatch.setenv("DRLAAS_AUTH_URI", client.app.state.settings.auth_uri)
    account = Account.create()
    gw = Gateway(str(client.base_url), account, client=client)
    assert chain_balance(gw, account.address) == 0
    assert ensure_gas(gw) == "funded"
    funded = chain_balance(gw, account.address)
    assert funded is not None and funded > 0
    assert ensure_gas(gw) == "has funds"
    assert chain_balance(gw, account.address) == funded  # no second top-up


def test_no_faucet_names_the_address(tmp_path: Path, service: ChainService) -> None:
    prod = Settings(data_dir=tmp_path / "data", mode="production", token_secret="s" * 40)
    with TestClient(create_app(prod, chain=service, indexer_interval=None)) as client:
        account = Account.create()
        gw = Gateway(str(client.base_url), account, client=client)
        with pytest.raises(NoGas, match=account.address):
            ensure_gas(gw)
