"""The CLI and the worker's client against a hostile gateway (a fake one on 127.0.0.1): it may
ask for any transaction to be signed (409 ``sign_locally``), relay another site's sign-in
message, name a CID the chain does not record, point the worker at directories of its choice,
and answer with the wrong JSON types. Nothing is signed or relayed that the command did not
mean (audit R1, R1b, R6, R7, R8)."""

from __future__ import annotations

import datetime as dt
import json
import threading
from collections.abc import Callable, Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import eth_abi
import pytest
from eth_account import Account
from typer.testing import CliRunner
from web3 import Web3

from backend.auth import SIWE_STATEMENT, SiweMessage
from backend.store import EmbeddedStore
from backend.store.bundle import upload_model
from backend.store.dag import compute_cid
from drlaas.cli import app
from drlaas.commands.client.session import CliGateway
from drlaas.commands.client.txcheck import MMC, TMC, UMC, contract, pin_file
from workers.daemon.funding import chain_balance, ensure_gas
from workers.daemon.gateway import Gateway, GatewayError
from workers.daemon.keys import load_or_create_key
from workers.daemon.links import (
    Deployment,
    DeploymentChanged,
    find_deployment,
    pinned_platform,
    record_pin,
    worker_settings,
)

CHAIN_ID = 31337
ADDRS = {UMC: "0x" + "11" * 20, TMC: "0x" + "22" * 20, MMC: "0x" + "33" * 20}
ATTACKER = "0x000000000000000000000000000000000000dEaD"
EXPERT = Path(__file__).resolve().parents[2] / "models" / "odmtl-2a"


class Fake:
    """A gateway whose answers the test chooses: ``routes[path](fake, body) -> (status,
    doc)``; ``seen`` lists (method, path, body) of every request."""

    def __init__(self) -> None:
        self.routes: dict[str, Callable[[Fake, Any], tuple[int, Any]]] = {}
        self.seen: list[tuple[str, str, Any]] = []
        self.siwe_domain: str | None = None
        self.siwe_chain = CHAIN_ID
        self.contracts: dict[str, Any] = {**ADDRS, "chain_id": CHAIN_ID, "rpc": None}
        fake = self

        class H(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def log_message(self, *a: Any) -> None:
                pass

            def _go(self) -> None:
                n = int(self.headers.get("content-length") or 0)
                raw = self.rfile.read(n) if n else b""
                body = json.loads(raw) if raw else None
                path = self.path.split("?")[0]
                fake.seen.append((self.command, path, body))
                route = fake.routes.get(path) or next(
                    (f for p, f in fake.routes.items() if p.endswith("*")
                     and path.startswith(p[:-1])), None)
                status, doc = route(fake, body) if route else (404, {"detail": "no"})
                data = doc if isinstance(doc, bytes) else json.dumps(doc).encode()
                self.send_response(status)
                ctype = "application/octet-stream" if isinstance(doc, bytes) else "application/json"
                self.send_header("content-type", ctype)
                self.send_header("content-length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            do_GET = do_POST = _go

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), H)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        self.routes.update(
            {
                "/api/auth/nonce": Fake.nonce,
                "/api/auth/token": lambda f, b: (200, {"access_token": "t"}),
                "/api/chain/contracts": lambda f, b: (200, f.contracts),
                "/api/tx": lambda f, b: (200, {"tx_hash": "0x" + "ab" * 32, "block_number": 1,
                                               "status": 1, "events": []}),
            }
        )
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def nonce(self, body: Any) -> tuple[int, Any]:
        host = self.siwe_domain or self.url.removeprefix("http://")
        now = dt.datetime.now(dt.UTC).replace(microsecond=0)
        msg = SiweMessage(domain=host, address=body["address"], statement=SIWE_STATEMENT,
                          uri=f"http://{host}", chain_id=self.siwe_chain, nonce="abcdef0123456789",
                          issued_at=now, expiration_time=now + dt.timedelta(minutes=5))
        return 200, {"message": msg.text()}

    def posted(self, path: str) -> list[Any]:
        return [b for m, p, b in self.seen if m == "POST" and p == path]


@pytest.fixture
def fake(data_dir: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Fake]:
    for var in ("DRLAAS_CHAIN_ID", "DRLAAS_KEY", "DRLAAS_TX_MAX_GAS",
                "DRLAAS_TX_MAX_FEE_PER_GAS_WEI", "DRLAAS_AUTH_DOMAIN", "DRLAAS_AUTH_URI",
                "DRLAAS_DATA_DIR"):
        monkeypatch.delenv(var, raising=False)
    f = Fake()
    yield f
    f.server.shutdown()


def call_data(name: str, fn: str, *args: Any) -> str:
    return str(contract(name).encode_abi(fn, list(args)))


def review_tx(address: str, **change: Any) -> dict[str, Any]:
    """What the real gateway sends for ``model review 1 --model 1 --review 5``."""
    tx = {"from": address, "to": ADDRS[MMC], "value": 0, "nonce": 0, "chainId": CHAIN_ID,
          "gas": 120_000, "maxFeePerGas": 2 * 10**9, "maxPriorityFeePerGas": 0, "type": 2,
          "data": call_data(MMC, "updateModelRep", 1, 1, 5)}
    tx.update(change)
    return {k: v for k, v in tx.items() if v is not None}


def answer_review_with(fake: Fake, address: str, then: str = "", **change: Any) -> None:
    detail = {"rule": "sign_locally", "msg": "sign it", "tx": review_tx(address, **change)}
    if then:
        detail["then"] = then
    fake.routes["/api/models/requests/1/reviews"] = lambda f, b: (409, {"detail": detail})


def review(fake: Fake, key: Path, **env: str) -> Any:
    return CliRunner().invoke(
        app,
        ["model", "review", "1", "--model", "1", "--review", "5", "--key", str(key),
         "--gateway", fake.url],
        env=env or None,
    )


def test_a_well_formed_review_is_signed_and_relayed_and_the_deployment_pinned(
    fake: Fake, tmp_path: Path
) -> None:
    key = tmp_path / "me.key"
    me = load_or_create_key(key).address
    answer_review_with(fake, me)
    res = review(fake, key)
    assert res.exit_code == 0, res.output
    (relayed,) = fake.posted("/api/tx")
    assert Account.recover_transaction(relayed["raw"]) == me
    pins = json.loads(pin_file(key).read_text())
    assert pins[fake.url] == {"chain_id": CHAIN_ID,
                              "contracts": {n: Web3.to_checksum_address(a)
                                            for n, a in ADDRS.items()}}


HOSTILE: dict[str, tuple[dict[str, Any], str]] = {
    "a transfer to another address": (
        {"to": ATTACKER, "value": 5 * 10**18, "chainId": 1, "data": "0x", "gas": 21_000},
        "chainId is 1, expected 31337",
    ),
    "the review on another chain": ({"chainId": 1}, "chainId is 1, expected 31337"),
    "a transfer on this chain": (
        {"to": ATTACKER, "value": 10**18, "data": "0x"}, f"to is {ATTACKER}, none of"),
    "another function": (
        {"to": ADDRS[UMC], "data": call_data(UMC, "setAdmin", ATTACKER, True)},
        "data calls UsersManager.setAdmin",
    ),
    "another review": (
        {"data": call_data(MMC, "updateModelRep", 1, 1, 0)},
        "argument review of ModelsManager.updateModelRep is 0, expected 5",
    ),
    "the review with a payment": ({"value": 10**18}, "value is 1000000000000000000 wei, "
                                  "expected 0 wei"),
    "a fee of 500 gwei": ({"maxFeePerGas": 500 * 10**9}, "maxFeePerGas is 500000000000 wei"),
    "a legacy gas price of 500 gwei": (
        {"type": 0, "maxFeePerGas": None, "maxPriorityFeePerGas": None,
         "gasPrice": hex(500 * 10**9)}, "gasPrice is 500000000000 wei"),
    "40M gas": ({"gas": 40_000_000}, "gas is 40000000, expected at most 30000000"),
    "trailing bytes after the call": (
        {"data": call_data(MMC, "updateModelRep", 1, 1, 5) + "00"}, "not the exact encoding"),
    "an EIP-7702 field": ({"authorizationList": [{"address": ATTACKER}]},
                          "unexpected field(s) authorizationList"),
    "another sender": ({"from": ATTACKER}, f"from is '{ATTACKER}'"),
}


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_a_transaction_the_command_did_not_mean_is_neither_signed_nor_relayed(
    fake: Fake, tmp_path: Path, case: str
) -> None:
    key = tmp_path / "me.key"
    change, reason = HOSTILE[case]
    answer_review_with(fake, load_or_create_key(key).address, **change)
    res = review(fake, key)
    assert res.exit_code == 1, res.output
    assert "tx_refused by this client" in res.output and reason in res.output, res.output
    assert "-> 409" not in res.output  # the client refused: no HTTP status of the gateway's
    assert "nothing was signed" in res.output
    assert fake.posted("/api/tx") == []  # nothing relayed, nothing sent anywhere else
    assert [p for _, p, _ in fake.seen if p == "/rpc"] == []


def test_a_first_step_the_route_does_not_take_is_refused(fake: Fake, tmp_path: Path) -> None:
    key = tmp_path / "me.key"
    address = load_or_create_key(key).address
    answer_review_with(fake, address, then="repeat",
                       to=ADDRS[TMC], data=call_data(TMC, "commitCid", b"\x01" * 32))
    res = review(fake, key)
    assert res.exit_code == 1 and "data calls TasksManager.commitCid" in res.output, res.output
    assert fake.posted("/api/tx") == []


def test_contracts_that_change_after_the_first_use_are_refused(
    fake: Fake, tmp_path: Path
) -> None:
    key = tmp_path / "me.key"
    address = load_or_create_key(key).address
    answer_review_with(fake, address)
    assert review(fake, key).exit_code == 0  # pinned now
    moved = "0x" + "44" * 20
    fake.contracts = {**fake.contracts, MMC: moved}  # "redeployed": the gateway says so too
    answer_review_with(fake, address, to=moved)
    res = review(fake, key)
    assert res.exit_code == 1, res.output
    assert f"to is {Web3.to_checksum_address(moved)}" in res.output
    assert str(pin_file(key)) in res.output and "to pin it again" in res.output
    assert len(fake.posted("/api/tx")) == 1  # the first review only


def test_a_real_redeployment_is_pinned_again_after_pin_forget(
    fake: Fake, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`drlaas pin forget` (the command the refusal names) drops the CLI's and the key's
    worker's pins for that gateway URL only; the next use pins what the gateway names then."""
    monkeypatch.setenv("DRLAAS_DATA_DIR", str(tmp_path / "data"))
    key = tmp_path / "me.key"
    address = load_or_create_key(key).address
    answer_review_with(fake, address)
    assert review(fake, key).exit_code == 0  # the CLI pinned the deployment
    worker_pins = tmp_path / "data" / "workers" / address / "platform.json"
    record_pin(worker_pins, fake.url, Deployment(ADDRS[UMC], ADDRS[TMC], ADDRS[MMC]), CHAIN_ID)
    record_pin(worker_pins, "http://elsewhere:8000", Deployment(*ADDRS.values()), 7)
    shown = CliRunner().invoke(app, ["pin", "show", "--key", str(key)])
    assert shown.exit_code == 0 and shown.output.count(f"{fake.url}: chain {CHAIN_ID}") == 2

    moved = "0x" + "44" * 20
    fake.contracts = {**fake.contracts, MMC: moved}  # really redeployed
    answer_review_with(fake, address, to=moved)
    refused = review(fake, key)
    assert f"drlaas pin forget --gateway {fake.url} --key {key}" in refused.output
    forget = CliRunner().invoke(app, ["pin", "forget", "--gateway", fake.url, "--key", str(key)])
    assert forget.exit_code == 0 and "(cli and worker)" in forget.output, forget.output
    assert list(json.loads(worker_pins.read_text())) == ["http://elsewhere:8000"]
    assert review(fake, key).exit_code == 0  # pinned again, on the new deployment
    pinned = json.loads(pin_file(key).read_text())[fake.url]["contracts"]
    assert pinned[MMC] == Web3.to_checksum_address(moved)
    again = CliRunner().invoke(app, ["pin", "forget", "--gateway", "http://nowhere", "--key",
                                     str(key)])
    assert again.exit_code == 0 and "nothing was pinned" in again.output


def test_the_deployment_can_be_pinned_from_the_environment(fake: Fake, tmp_path: Path) -> None:
    key = tmp_path / "me.key"
    answer_review_with(fake, load_or_create_key(key).address)
    other = ",".join("0x" + c * 40 for c in "567")
    res = review(fake, key, DRLAAS_CONTRACTS=other, DRLAAS_CHAIN_ID=str(CHAIN_ID))
    assert res.exit_code == 1 and "none of the platform's contracts" in res.output, res.output
    fake.siwe_chain = 7  # a sign-in for chain 7 (else refused before, by its chain id)...
    res = review(fake, key, DRLAAS_CONTRACTS=",".join(ADDRS.values()), DRLAAS_CHAIN_ID="7")
    assert res.exit_code == 1 and "chainId is 31337, expected 7" in res.output, res.output
    fake.siwe_chain = CHAIN_ID  # ...and a transaction for chain 31337
    assert fake.posted("/api/tx") == [] and not pin_file(key).exists()
    ok = review(fake, key, DRLAAS_CONTRACTS=json.dumps(ADDRS), DRLAAS_CHAIN_ID=str(CHAIN_ID))
    assert ok.exit_code == 0, ok.output


def test_task_submit_signs_only_its_own_terms_and_escrow(fake: Fake, tmp_path: Path) -> None:
    key = tmp_path / "me.key"
    me = load_or_create_key(key).address
    spec = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
    terms = (0, 2, 0, 0, 0, 0, 3600, spec)
    tx = review_tx(me, to=ADDRS[TMC], value=2 * 10**15,
                   data=call_data(TMC, "addTask", terms))
    fake.routes["/api/tasks"] = lambda f, b: (409, {"detail": {"rule": "sign_locally",
                                                               "msg": "", "tx": tx}})
    args = ["task", "submit", "--key", str(key), "--gateway", fake.url, "--workers", "2",
            "--payment-wei", str(10**15), "--deadline-s", "3600", "--public-outcome"]
    tx["value"] = 2 * 10**16  # ten times the escrow asked for
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 1 and "value is 20000000000000000 wei, expected 2000000000000000" \
        in res.output, res.output
    tx["value"] = 2 * 10**15
    tx["data"] = call_data(TMC, "addTask", (0, 2, 0, 0, 0, 0, 10**9, spec))  # another deadline
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 1 and "argument p.duration of TasksManager.addTask is 1000000000" \
        in res.output, res.output
    assert fake.posted("/api/tx") == []


def test_a_relayed_sign_in_message_of_another_site_is_not_signed(
    fake: Fake, tmp_path: Path
) -> None:
    fake.siwe_domain = "gateway.real-consortium.example"
    gw = Gateway(fake.url, Account.create())
    with pytest.raises(GatewayError, match="not signed: the message is for domain"):
        gw.sign_in()
    assert fake.posted("/api/auth/token") == []
    fake.siwe_domain = None
    assert gw.sign_in() == "t"  # its own message is signed
    other = Gateway(fake.url.replace("127.0.0.1", "localhost"), Account.create())
    assert other.sign_in() == "t"  # loopback names are one host


def test_a_sign_in_message_for_another_chain_is_not_signed_once_the_chain_is_known(
    fake: Fake, tmp_path: Path
) -> None:
    """A gateway relaying the sign-in of a platform on another chain (same names, another
    consortium): the worker knows its chain from its node, the CLI from its pin."""
    fake.siwe_chain = 1
    worker = Gateway(fake.url, Account.create(), chain_id=CHAIN_ID)
    with pytest.raises(GatewayError, match="not signed: the message is for chain 1, not"):
        worker.sign_in()
    key = tmp_path / "me.key"
    cli = CliGateway(fake.url, load_or_create_key(key), key)
    assert cli.sign_in() == "t"  # nothing pinned yet: the chain is not known
    fake.siwe_chain = CHAIN_ID
    answer_review_with(fake, load_or_create_key(key).address)
    assert review(fake, key).exit_code == 0  # the first write pins the deployment
    fake.siwe_chain = 1
    cli = CliGateway(fake.url, load_or_create_key(key), key)
    with pytest.raises(GatewayError, match=f"the message is for chain 1, not .* {CHAIN_ID}"):
        cli.sign_in()
    assert len(fake.posted("/api/auth/token")) == 2  # the two signed before the change
    fake.siwe_chain = CHAIN_ID
    assert worker.sign_in() == cli.sign_in() == "t"


def test_the_worker_pins_the_gateways_deployment_on_first_use(
    fake: Fake, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from backend.settings import load_settings

    monkeypatch.delenv("DRLAAS_CONTRACTS", raising=False)
    settings = load_settings(data_dir=str(tmp_path / "d"))
    pins = tmp_path / "worker" / "platform.json"
    first = pinned_platform(settings, fake.url, pins)
    assert (first.chain_id, first.pin_file) == (CHAIN_ID, pins)  # to record once connected
    assert first.deployment == Deployment(ADDRS[UMC], ADDRS[TMC], ADDRS[MMC])
    record_pin(pins, fake.url + "/", first.deployment, CHAIN_ID)
    again = pinned_platform(settings, fake.url, pins)
    assert (again.deployment, again.chain_id, again.pin_file) == (first.deployment, CHAIN_ID, None)
    moved = "0x" + "44" * 20
    fake.contracts = {**fake.contracts, MMC: moved}  # the gateway names its own MMC now
    with pytest.raises(DeploymentChanged, match=f"pinned chain {CHAIN_ID} .*{pins}"):
        pinned_platform(settings, fake.url, pins)
    fake.contracts = {**ADDRS, "chain_id": 1, "rpc": None}  # ... or another chain
    with pytest.raises(DeploymentChanged, match="names chain 1"):
        pinned_platform(settings, fake.url, pins)
    other = pinned_platform(settings, fake.url.replace("127.0.0.1", "localhost"), pins)
    assert other.pin_file == pins  # another gateway URL: its own first use
    # the operator's deployment is taken as it is, and pins nothing
    monkeypatch.setenv("DRLAAS_CONTRACTS", json.dumps({**ADDRS, MMC: moved}))
    named = pinned_platform(settings, fake.url, pins)
    assert named.deployment.mmc == moved and named.pin_file is None
    monkeypatch.delenv("DRLAAS_CONTRACTS")
    pins.write_text("{not json")  # never silently pinned again
    with pytest.raises(ValueError, match="unreadable pin file"):
        pinned_platform(settings, fake.url, pins)


def test_a_gateway_known_by_another_name_is_named_by_the_operator(
    fake: Fake, monkeypatch: pytest.MonkeyPatch
) -> None:
    """docker-compose: workers reach http://gateway:8000, which signs in as the public name;
    the name they share with it (DRLAAS_AUTH_DOMAIN / _URI) is accepted, no other."""
    fake.siwe_domain = "drlaas.example.org"
    gw = Gateway(fake.url, Account.create())
    with pytest.raises(GatewayError, match="set DRLAAS_AUTH_DOMAIN"):
        gw.sign_in()
    monkeypatch.setenv("DRLAAS_AUTH_DOMAIN", "drlaas.example.org")
    with pytest.raises(GatewayError, match="is for URI"):  # the URI must be named too
        gw.sign_in()
    monkeypatch.setenv("DRLAAS_AUTH_URI", "http://drlaas.example.org")
    assert gw.sign_in() == "t"
    fake.siwe_domain = "other.example.org"
    with pytest.raises(GatewayError, match="not signed"):
        gw.sign_in()
    assert len(fake.posted("/api/auth/token")) == 1


def test_task_pull_checks_the_gateways_cid_on_chain(fake: Fake, tmp_path: Path) -> None:
    store = EmbeddedStore(tmp_path / "ipfs", fsync=False)
    cid = upload_model(store, EXPERT)  # a public zoo model: not the worker's sealed outcome
    worker = Web3.to_checksum_address("0x" + "77" * 20)
    record: list[Any] = [worker, 7]
    fake.contracts = {**fake.contracts, "rpc": "/rpc"}
    fake.routes["/api/tasks/7"] = lambda f, b: (200, {"outcomes": [{"worker": worker,
                                                                   "cid": cid}]})
    fake.routes["/api/blocks/*"] = lambda f, b: (200, store.get(f.seen[-1][1].split("/")[-1]))

    def rpc(f: Fake, body: Any) -> tuple[int, Any]:
        if body["method"] == "eth_chainId":
            return 200, {"jsonrpc": "2.0", "id": body["id"], "result": hex(CHAIN_ID)}
        assert body["method"] == "eth_call" and body["params"][0]["to"].lower() == ADDRS[TMC]
        out = eth_abi.encode(["address", "uint256", "uint8"], [record[0], record[1], 0])
        return 200, {"jsonrpc": "2.0", "id": body["id"], "result": "0x" + out.hex()}

    fake.routes["/rpc"] = rpc
    key = tmp_path / "req.key"
    load_or_create_key(key)

    def pull(*extra: str) -> Any:
        return CliRunner().invoke(app, ["task", "pull", "7", "--gateway", fake.url,
                                        "--out", str(tmp_path / "out"), *extra])

    record[:] = ["0x" + "00" * 20, 0]  # the chain records no outcome with this CID
    res = pull("--key", str(key))
    assert res.exit_code == 1 and "the chain records no outcome with that CID" in res.output
    record[:] = [Web3.to_checksum_address("0x" + "88" * 20), 7]  # another worker's
    res = pull("--key", str(key))
    assert res.exit_code == 1 and "records it as" in res.output, res.output
    assert not any(p.startswith("/api/blocks/") for _, p, _ in fake.seen)
    record[:] = [worker, 7]  # on chain, but not sealed although --key asks for a sealed one
    res = pull("--key", str(key))
    assert res.exit_code == 1 and "is not sealed" in res.output, res.output
    assert not (tmp_path / "out").exists()
    res = pull()  # a public outcome, on chain: pulled
    assert res.exit_code == 0, res.output
    weights = (tmp_path / "out" / "model.safetensors").read_bytes()
    assert compute_cid(weights) == compute_cid((EXPERT / "model.safetensors").read_bytes())


def test_local_services_are_taken_from_a_loopback_gateway_only_and_as_absolute_paths(
    fake: Fake, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("DRLAAS_IPFS", raising=False)
    monkeypatch.delenv("DRLAAS_BROKER", raising=False)
    good = {"data_dir": str(tmp_path / "gw"), "broker_embedded": True,
            "ipfs_dir": str(tmp_path / "gw" / "ipfs")}
    answer: dict[str, Any] = dict(good)
    fake.routes["/api/local/services"] = lambda f, b: (200, answer)
    settings, _ = worker_settings(fake.url)
    assert settings.data_dir == tmp_path / "gw"
    for bad in ("relative/dir", str(tmp_path / "gw" / ".." / ".." / "etc")):
        answer.update(ipfs_dir=bad)
        with pytest.raises(RuntimeError, match="not an absolute path without '..'"):
            worker_settings(fake.url)
    answer.update(good, data_dir=str(tmp_path / "gw" / ".." / "x"))
    with pytest.raises(RuntimeError, match="data_dir"):
        worker_settings(fake.url)
    answer.update(good)
    fake.seen.clear()
    with pytest.raises(RuntimeError, match="not a loopback address"):
        worker_settings("http://gateway.example:8000")
    assert fake.seen == []


def test_answers_of_the_wrong_type_are_gateway_errors_and_rpc_stays_on_the_gateway(
    fake: Fake, tmp_path: Path
) -> None:
    other = Fake()  # another host: the gateway must not make the client POST there
    try:
        gw = Gateway(fake.url, Account.create())
        fake.contracts = [1, 2, 3]  # type: ignore[assignment]
        with pytest.raises(GatewayError, match="not a JSON object"):
            ensure_gas(gw)
        fake.contracts = {"rpc": other.url + "/internal-admin"}
        with pytest.raises(GatewayError, match="only a path on the gateway"):
            chain_balance(gw, gw.address)
        assert other.seen == []
        fake.contracts = {"rpc": "/rpc"}
        fake.routes["/rpc"] = lambda f, b: (200, {"jsonrpc": "2.0", "id": 1, "result": "0xzz"})
        with pytest.raises(GatewayError, match="not a hex quantity"):
            chain_balance(gw, gw.address)
        fake.contracts = [1, 2, 3]  # type: ignore[assignment]
        from backend.settings import load_settings

        with pytest.raises(RuntimeError, match="not a JSON object"):
            find_deployment(load_settings(data_dir=str(tmp_path / "d")), fake.url)
    finally:
        other.server.shutdown()
