"""The worker daemon against a hostile or broken IPFS node and gateway, and killed at awkward
moments: every offer is answered, progress stays best effort, kills are counted, and a job
killed before its acceptOffer is not lost."""

from __future__ import annotations

import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import httpx
import pytest
from eth_account import Account

import workers.daemon.handler as H
from backend.chain.platform import OfferState, TaskStatus
from backend.store import EmbeddedStore, StoreError, StoreUnavailable
from backend.store.cid import CID, RAW
from backend.store.ipfs_rpc import IpfsRpcStore
from workers.daemon.gateway import Gateway, GatewayError

SOME_CID = "bafkreihdwdcefgh4dqkjv67uzcmw7ojee6xedzdetojuzjevtenxquvyku"
SPEC = {
    "env": {"rows": 6, "cols": 6, "agents": 1},
    "observation": {"kind": "odmtl", "window": 3},
    "budget": {"steps": 64},
}


class FakeTMC:
    """The offer and task of one worker; transactions move the offer as the TMC does."""

    def __init__(self, state: OfferState = OfferState.OFFERED, expiry: float | None = None):
        self.state, self.calls = state, []  # type: ignore[var-annotated]
        self.expiry = int(time.time()) + 3600 if expiry is None else int(expiry)
        self.deadline = int(time.time()) + 86400  # fixed: the job records its task's

    def offer(self, tid: int, addr: str) -> dict[str, Any]:
        return {"state": self.state, "expiry": self.expiry}

    def task(self, tid: int) -> dict[str, Any]:
        return {"status": TaskStatus.OPEN, "requester": "0x" + "11" * 20,
                "deadline": self.deadline, "domain": 0}

    def transact(self, fn: str, *args: Any, sender: str | None = None) -> Any:
        self.calls.append(fn)
        self.state = {"acceptOffer": OfferState.ACCEPTED, "declineOffer": OfferState.DECLINED,
                      "abandonOffer": OfferState.FAILED}.get(fn, self.state)
        return SimpleNamespace(tx_hash="0x00")


def _handler(
    monkeypatch: pytest.MonkeyPatch, store: Any, data_dir: Path, spec_cid: str,
    tmc: FakeTMC | None = None,
) -> tuple[H.OfferHandler, FakeTMC]:
    tmc = tmc or FakeTMC()
    platform = SimpleNamespace(tmc=tmc, identity="testchain",
                               chain=SimpleNamespace(now=lambda: int(time.time())))
    monkeypatch.setattr(H, "task_spec_cid", lambda platform, task_id: spec_cid)
    h = H.OfferHandler(account=Account.create(), platform=platform, store=store,  # type: ignore[arg-type]
                       data_dir=data_dir, memory_bytes=16 * 2**30)
    return h, tmc


# -- the IPFS node's answers -------------------------------------------------------------------
def test_an_undecodable_answer_is_a_store_error_and_the_offer_is_declined(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """200 with Content-Encoding: gzip and a body that is not gzip (httpx.DecodingError)."""
    def reply(request: httpx.Request) -> httpx.Response:
        return httpx.Response(200, headers={"Content-Encoding": "gzip"}, content=b"not gzip")

    store = IpfsRpcStore("http://node:5001", transport=httpx.MockTransport(reply), retries=0)
    with pytest.raises(StoreError, match="answered block/get wrongly: DecodingError"):
        store.get(SOME_CID, max_size=1000)
    h, tmc = _handler(monkeypatch, store, tmp_path, SOME_CID)
    out = h.handle(1, h.address)
    assert out["status"] == "declined" and "DecodingError" in out["reason"]
    assert tmc.calls == ["declineOffer"]
    assert json.loads((h.job_dir(1) / "state.json").read_text())["phase"] == "declined"


def test_a_store_failing_otherwise_still_gets_the_offer_declined(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    store = EmbeddedStore(tmp_path / "ipfs", fsync=False)

    def broken(*args: Any, **kw: Any) -> bytes:
        raise RuntimeError("a bug of the store")

    monkeypatch.setattr(store, "get", broken)
    h, tmc = _handler(monkeypatch, store, tmp_path / "data", SOME_CID)
    out = h.handle(1, h.address)
    assert out["status"] == "declined" and "a bug of the store" in out["reason"]
    assert tmc.calls == ["declineOffer"]


def test_a_node_answering_no_json_object_is_a_store_error() -> None:
    store = IpfsRpcStore("http://node:5001", retries=0, transport=httpx.MockTransport(
        lambda r: httpx.Response(200, content=b"[1]")))
    with pytest.raises(StoreError, match="no JSON object"):
        store.pins()


def test_a_trickling_node_meets_the_block_deadline() -> None:
    """A byte every 0.3 s never trips a 1 s read timeout; the deadline of the whole block
    read does."""
    data = b"A" * 12

    class Trickle(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args: Any) -> None:
            pass

        def do_POST(self) -> None:
            self.send_response(200)
            self.send_header("Transfer-Encoding", "chunked")
            self.end_headers()
            try:
                for b in data:
                    self.wfile.write(b"1\r\n" + bytes([b]) + b"\r\n")
                    self.wfile.flush()
                    time.sleep(0.3)
                self.wfile.write(b"0\r\n\r\n")
            except OSError:
                pass

    srv = ThreadingHTTPServer(("127.0.0.1", 0), Trickle)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        store = IpfsRpcStore(f"http://127.0.0.1:{srv.server_port}", timeout=1.0, deadline=0.8,
                             retries=0)
        start = time.monotonic()
        with pytest.raises(StoreUnavailable, match="not received within 0.8 s"):
            store.get(str(CID.for_block(data, RAW)), max_size=1000)
        assert time.monotonic() - start < 2.5
        assert IpfsRpcStore("http://x:1", timeout=30).deadline == 120
    finally:
        srv.shutdown()


# -- training starts -----------------------------------------------------------------------------
class _Killed(BaseException):
    """The OOM killer, mid-download (nothing of the process runs after it)."""


def test_a_start_killed_while_fetching_experts_is_counted(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    store = EmbeddedStore(tmp_path / "ipfs", fsync=False)
    spec_cid = store.add(json.dumps({**SPEC, "experts": [SOME_CID]}).encode())
    h, _ = _handler(monkeypatch, store, tmp_path / "data", spec_cid,
                    FakeTMC(OfferState.ACCEPTED))
    h._save(1, phase="accepted")

    def killed(*args: Any, **kw: Any) -> Any:
        raise _Killed

    monkeypatch.setattr(H, "fetch_experts", killed)
    for delivery in (1, 2):
        with pytest.raises(_Killed):
            h.handle(1, h.address)
        assert h._state(1)["starts_without_progress"] == delivery

    def store_down(*args: Any, **kw: Any) -> Any:  # an outage is not a process dying
        raise StoreUnavailable("http://node", "down")

    monkeypatch.setattr(H, "fetch_experts", store_down)
    with pytest.raises(H.Transient):
        h.handle(1, h.address)
    assert h._state(1)["starts_without_progress"] == 2
    monkeypatch.setattr(H, "fetch_experts", killed)
    with pytest.raises(_Killed):
        h.handle(1, h.address)
    out = h.handle(1, h.address)  # the third start died too: given back
    assert out["status"] == "failed" and "JobKeepsDying" in out["reason"]


# -- progress ------------------------------------------------------------------------------------
MALFORMED = {
    "200 JSON content type, HTML body": lambda r: httpx.Response(
        200, headers={"content-type": "application/json"}, content=b"<html>portal</html>"),
    "502 with a JSON list": lambda r: httpx.Response(502, json=["bad gateway"]),
    "nonce answer without message": lambda r: httpx.Response(200, json={"msg": "x"}),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_gateway_answers_are_gateway_errors_and_progress_goes_on(
    case: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    transport = httpx.MockTransport(MALFORMED[case])
    account = Account.create()
    gw = Gateway("http://gw", account,
                 client=httpx.Client(base_url="http://gw", transport=transport))
    with pytest.raises(GatewayError):
        gw.post("/tasks/1/progress", json={"step": 1}, auth=True)
    h, _ = _handler(monkeypatch, EmbeddedStore(tmp_path / "ipfs", fsync=False), tmp_path, "x")
    h.gateway = gw
    h._post_progress(1, {"step": 1, "success": 0.0, "time": 1.0, "cost": 1.0})  # no raise
    h._flush_progress(1, wait_s=0.3)  # the last flush before submitOutcome neither


# -- recovery ------------------------------------------------------------------------------------
def test_a_job_killed_before_its_accept_offer_is_queued_again(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Killed after saving ``accepting``, before acceptOffer was sent, and the broker lost
    the message: the offer is still live on chain, so the job is queued, not closed; once the
    offer has expired it is closed."""
    store = EmbeddedStore(tmp_path / "ipfs", fsync=False)
    h, tmc = _handler(monkeypatch, store, tmp_path / "data", "x", FakeTMC(OfferState.OFFERED))
    h._save(7, phase="accepting")
    queued: list[int] = []
    done = h.recover(enqueue=lambda tid, worker: queued.append(tid))
    assert done["queued"] == [7] and queued == [7]
    assert h._state(7)["phase"] == "accepting"
    assert h.active_jobs(exclude=0) == [7]
    tmc.expiry = int(time.time()) - 1
    done = h.recover(enqueue=lambda tid, worker: queued.append(tid))
    assert done["closed"] == [7] and queued == [7]
