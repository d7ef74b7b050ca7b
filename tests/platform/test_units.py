"""Small pieces of the daemon: capabilities, manifest checks, job keys, backoff."""

from __future__ import annotations

import random
from pathlib import Path

import pytest

from backend.store import EmbeddedStore, InvalidContent
from backend.store.bundle import pull_model, read_bundle, upload_model
from workers.daemon.capabilities import measure, ram_bytes, ram_gb
from workers.daemon.command import parse_domains
from workers.daemon.tasks import RETRY_CAP_S, make_on_offer, offer_key, retry_delay


def test_ram_is_read_from_meminfo(tmp_path: Path) -> None:
    f = tmp_path / "meminfo"
    f.write_text("MemTotal:       16318404 kB\nMemFree:  1 kB\n")
    assert ram_gb(f) == 15  # 15.56 GiB, whole GiB rounded down
    assert ram_bytes(f) == 16318404 * 1024
    f.write_text("MemFree: 1 kB\n")
    with pytest.raises(ValueError, match="MemTotal"):
        ram_gb(f)
    caps = measure()
    assert caps.cpu_cores >= 1 and caps.ram_gb >= 1 and caps.gpu_series == 0  # CPU-only torch


def test_manifest_round_trip_and_rejects_other_documents(tmp_path: Path) -> None:
    store = EmbeddedStore(tmp_path / "ipfs")
    model = tmp_path / "model"
    model.mkdir()
    (model / "model.safetensors").write_bytes(b"\x00weights" * 100)
    (model / "model.json").write_text('{"card": 1}')
    cid = upload_model(store, model)
    files = read_bundle(store, cid)
    assert files["model.json"] == (store.add((model / "model.json").read_bytes()), 11)
    out = pull_model(store, cid, tmp_path / "pulled")
    assert (out / "model.safetensors").read_bytes() == (model / "model.safetensors").read_bytes()
    not_manifest = store.add(b'{"format": "something-else", "files": {}}')
    with pytest.raises(InvalidContent, match="not a drlaas-bundle/1 manifest"):
        read_bundle(store, not_manifest)
    (model / "model.json").unlink()
    with pytest.raises(FileNotFoundError, match="model.json"):
        upload_model(store, model)


def test_offer_jobs_use_idempotent_keys_on_per_worker_queues() -> None:
    sent = []

    class FakeApp:
        def send_task(self, name, args, queue, task_id):  # noqa: ANN001
            sent.append((name, args, queue, task_id))

    hook = make_on_offer(None, FakeApp())  # type: ignore[arg-type]
    w = "0x7e5f4552091a69125d5dfcb7b8c2659029395bdf"
    hook(5, w)
    hook(5, w.upper().replace("0X", "0x"))
    (name, args, queue, key), again = sent
    assert again == sent[0]  # same offer, same key, whatever the address case
    assert name == "drlaas.handle_offer" and args == [
        5,
        "0x7E5F4552091A69125d5DfCb7b8C2659029395Bdf",
    ]
    assert queue == "worker.0x7E5F4552091A69125d5DfCb7b8C2659029395Bdf" and key == offer_key(5, w)


def test_retry_backoff_grows_is_jittered_and_capped() -> None:
    rng = random.Random(0)
    early = [retry_delay(0, rng=rng) for _ in range(200)]
    late = [retry_delay(20, rng=rng) for _ in range(200)]
    assert 0.5 <= min(early) and max(early) <= 2.0
    assert max(late) <= RETRY_CAP_S and len(set(late)) > 100 and max(late) > 10 * max(early)


def test_domains_option() -> None:
    assert parse_domains("0,3,5-7") == (0, 3, 5, 6, 7)
    with pytest.raises(ValueError, match="expected codes"):
        parse_domains("all")  # 48 codes, where a worker covers at most 4
    with pytest.raises(ValueError, match="0-47"):
        parse_domains("48")


def test_celery_job_retries_transient_errors_only(tmp_path: Path) -> None:
    from backend.celery_app import make_celery
    from backend.settings import load_settings
    from workers.daemon import tasks
    from workers.daemon.handler import Transient

    class Flaky:
        def __init__(self, exc: Exception) -> None:
            self.exc = exc
            self.calls = 0

        def handle(self, task_id: int, worker: str) -> dict:
            self.calls += 1
            raise self.exc

        def delivery_time_left(self, task_id: int) -> float | None:
            return None  # no trained model: given back once the retries ran out

        def give_up(self, task_id: int, reason: str) -> dict:
            self.given_up = reason
            return {"task_id": task_id, "status": "failed", "reason": reason}

    app = make_celery(load_settings(data_dir=tmp_path))
    app.finalize()
    job = app.tasks[tasks.TASK_NAME]
    assert job.acks_late and job.reject_on_worker_lost
    w = "0x7e5f4552091a69125d5dfcb7b8c2659029395bdf"
    try:
        # eager apply runs the retries at once: a transient error is retried up to the cap
        down = Flaky(Transient("content store unavailable at http://x: refused"))
        tasks.set_runtime(down)  # type: ignore[arg-type]
        res = job.apply(args=[1, w], task_id=tasks.offer_key(1, w))
        assert down.calls == tasks.MAX_RETRIES + 1
        # the last retry failed too: the job is given back (abandonOffer), not dropped
        assert res.state == "SUCCESS" and res.result["status"] == "failed"
        assert "content store unavailable" in down.given_up and "8 retries" in down.given_up
        bad = Flaky(ValueError("bad offer"))
        tasks.set_runtime(bad)  # type: ignore[arg-type]
        res = job.apply(args=[1, w], task_id=tasks.offer_key(1, w))
        assert bad.calls == 1 and isinstance(res.result, ValueError)  # never retried
    finally:
        tasks.set_runtime(None)


@pytest.fixture
def quick_pauses(monkeypatch: pytest.MonkeyPatch) -> None:
    from workers.daemon import progress_sender

    monkeypatch.setattr(progress_sender, "FIRST_PAUSE_S", 0.01)
    monkeypatch.setattr(progress_sender, "MAX_PAUSE_S", 0.05)


def test_progress_points_wait_for_the_gateway_index_and_keep_their_order(
    tmp_path: Path, quick_pauses: None
) -> None:
    from workers.daemon.gateway import GatewayError
    from workers.daemon.handler import OfferHandler

    class LaggingGateway:
        """Refuses points until the gateway's index has seen the acceptance (3rd call)."""

        def __init__(self) -> None:
            self.calls, self.got = 0, []

        def post(self, path: str, json: dict, auth: bool) -> None:  # noqa: A002
            self.calls += 1
            if self.calls < 3:
                raise GatewayError("POST", path, 403, {"rule": "not_assigned_worker", "msg": ""})
            if json["step"] == 2:
                raise GatewayError("POST", path, 409, {"rule": "progress_step_exists", "msg": ""})
            self.got.append(json["step"])

    gw = LaggingGateway()
    h = OfferHandler(account=None, platform=None, store=None, data_dir=tmp_path, gateway=gw)  # type: ignore[arg-type]
    for step in (1, 2, 3):
        h._post_progress(7, {"step": step})
    h._flush_progress(7, wait_s=10.0)
    # 1 waited for the index (two refusals), 2 was a duplicate: dropped, 3 went after it
    assert gw.got == [1, 3] and gw.calls == 5 and h._progress.pending(7) == []


def test_training_never_waits_on_the_gateway(tmp_path: Path) -> None:
    """A gateway that holds every post (slow, or hostile): the training loop's posts return
    at once and the points go once it answers, in order."""
    import threading

    from workers.daemon.handler import OfferHandler

    class HeldGateway:
        def __init__(self) -> None:
            self.gate, self.got = threading.Event(), []

        def post(self, path: str, json: dict, auth: bool) -> None:  # noqa: A002
            assert self.gate.wait(30), "never released"
            self.got.append(json["step"])

    gw = HeldGateway()
    h = OfferHandler(account=None, platform=None, store=None, data_dir=tmp_path, gateway=gw)  # type: ignore[arg-type]
    for step in range(50):
        h._post_progress(7, {"step": step})  # a synchronous post would hang here for 30 s
    assert not gw.gate.is_set() and gw.got == []
    assert not h._progress.flush(7, wait_s=0.05)  # held: the flush gives up at its deadline
    gw.gate.set()
    assert h._progress.flush(7, wait_s=30)
    assert gw.got == list(range(50))


def test_a_job_whose_points_the_gateway_refuses_holds_back_no_other_job(
    tmp_path: Path, quick_pauses: None
) -> None:
    """Two jobs at once (max_jobs 2): the gateway's index has not seen job 7's acceptance
    yet, so its points wait; job 8's go meanwhile."""
    from workers.daemon.gateway import GatewayError
    from workers.daemon.handler import OfferHandler

    class Gateway:
        def __init__(self) -> None:
            self.got: list[tuple[str, int]] = []

        def post(self, path: str, json: dict, auth: bool) -> None:  # noqa: A002
            if path.startswith("/tasks/7/"):
                raise GatewayError("POST", path, 403, {"rule": "not_assigned_worker", "msg": ""})
            self.got.append((path, json["step"]))

    gw = Gateway()
    h = OfferHandler(account=None, platform=None, store=None, data_dir=tmp_path, gateway=gw)  # type: ignore[arg-type]
    h._post_progress(7, {"step": 1})
    for step in (1, 2):
        h._post_progress(8, {"step": step})
    assert h._progress.flush(8, wait_s=10.0)
    assert gw.got == [("/tasks/8/progress", 1), ("/tasks/8/progress", 2)]
    assert h._progress.pending(7) == [{"step": 1}]  # still waiting for the index


def test_progress_points_queued_through_an_outage_are_bounded(
    tmp_path: Path, quick_pauses: None
) -> None:
    """While the gateway is down every point waits in a queue of at most MAX_PENDING_POINTS
    (the oldest dropped: progress.jsonl keeps them all); when it is back they go oldest
    first; a finished job's queue is dropped."""
    from types import SimpleNamespace

    from workers.daemon import handler as hd
    from workers.daemon.progress_sender import MAX_PENDING_POINTS

    class Gateway:
        def __init__(self) -> None:
            self.up, self.got = False, []

        def post(self, path: str, json: dict, auth: bool) -> None:  # noqa: A002
            if not self.up:
                raise ConnectionError("gateway down")
            self.got.append(json["step"])

    gw = Gateway()
    chain = SimpleNamespace(identity="chain-1")  # only the job directories' key is read
    h = hd.OfferHandler(account=None, platform=chain, store=None, data_dir=tmp_path, gateway=gw)  # type: ignore[arg-type]
    n = MAX_PENDING_POINTS + 100
    for step in range(n):
        h._post_progress(7, {"step": step})
    pending = h._progress.pending(7)
    assert len(pending) == MAX_PENDING_POINTS and pending[0]["step"] == 100
    gw.up = True
    h._flush_progress(7, wait_s=10.0)  # before submitting: the rest, in order
    # (one point taken while it was down may go first, if the queue had not dropped it yet)
    assert gw.got[-MAX_PENDING_POINTS:] == list(range(100, n)) and gw.got == sorted(gw.got)
    assert len(gw.got) <= MAX_PENDING_POINTS + 1 and h._progress.pending(7) == []
    gw.up = False
    h._post_progress(7, {"step": n})
    h._close(7, phase="failed")
    assert h._progress.pending(7) == []


def test_give_up_abandons_a_job_in_hand_and_declines_an_offer_being_checked(
    tmp_path: Path,
) -> None:
    """Out of retries: an accepted (trained, uploaded) job fails and is given back on chain;
    an offer still being checked is declined while the chain still offers it; one with no
    job, already submitted, or whose offer the chain no longer holds, is left as it is."""
    from types import SimpleNamespace

    from backend.chain.platform import OfferState, TaskStatus
    from workers.daemon.handler import OfferHandler

    offers = {4: OfferState.OFFERED, 5: OfferState.EXPIRED}
    tmc = SimpleNamespace(offer=lambda task_id, worker: {"state": int(offers[task_id])},
                          task=lambda task_id: {"status": int(TaskStatus.OPEN)})
    chain = SimpleNamespace(identity="chain-1", tmc=tmc)
    h = OfferHandler(account=SimpleNamespace(address="0xWorker"), platform=chain,  # type: ignore[arg-type]
                     store=None, data_dir=tmp_path)
    sent: list[tuple[str, int]] = []
    h._transact = lambda fn, task_id: sent.append((fn, task_id))  # type: ignore[method-assign]
    assert h.give_up(1, "store down")["status"] == "given up"  # no job state: never accepted
    h._save(2, phase="submitted", cid="bafy")
    assert h.give_up(2, "store down")["status"] == "given up"
    assert sent == []
    h._save(3, phase="uploaded", cid="bafy")
    out = h.give_up(3, "gave up after 8 retries: store down")
    assert out["status"] == "failed" and sent == [("abandonOffer", 3)]
    assert h._state(3)["phase"] == "failed" and "8 retries" in h._state(3)["reason"]
    h._save(4, phase="offered", offer_expiry=10**10)
    out = h.give_up(4, "gave up after 8 retries: cannot fetch task spec")
    assert out["status"] == "declined" and sent[-1] == ("declineOffer", 4)
    assert h._state(4)["phase"] == "declined" and "task spec" in h._state(4)["reason"]
    h._save(5, phase="offered", offer_expiry=1)
    assert h.give_up(5, "store down")["status"] == "given up" and len(sent) == 2


def test_recovery_at_start_never_stops_the_daemon_when_the_node_is_down(capsys) -> None:
    """``drlaas worker run`` reconciles its jobs before it consumes offers and says what it did
    on stderr; a node still down (or any other failure of the scan) is reported, and the daemon
    starts anyway; deferred jobs are retried in the background, only those, until none is
    left."""
    from workers.daemon.command import recover_jobs
    from workers.daemon.handler import Transient

    class Handler:
        def __init__(self, *results: dict | Exception) -> None:
            self.results, self.calls = list(results), []

        def recover(self, enqueue, only=None):
            self.calls.append((enqueue, only))
            result = self.results.pop(0)
            if isinstance(result, Exception):
                raise result
            return result

    down = Handler(Transient("chain node unreachable: refused"))
    assert recover_jobs(down, enqueue=print) is None
    assert down.calls == [(print, None)]
    assert "recovery at start skipped: Transient: chain node unreachable" in capsys.readouterr().err
    recover_jobs(Handler(PermissionError("jobs/7/state.json")), print)
    assert "skipped: PermissionError" in capsys.readouterr().err
    recover_jobs(Handler({"reported": [4], "queued": [], "closed": [], "pruned": [2, 3]}), print)
    assert "reported [4], pruned [2, 3]" in capsys.readouterr().err
    # two jobs deferred at start: retried (a failed pass keeps both), then one, then none left
    later = Handler({"queued": [1], "deferred": [5, 8]}, Transient("still down"),
                    {"queued": [5], "deferred": [8]}, {"closed": [8], "deferred": []})
    thread = recover_jobs(later, print, retry_s=0.01)
    assert thread is not None
    thread.join(timeout=10)
    assert not thread.is_alive() and later.results == []
    assert [only for _, only in later.calls] == [None, {5, 8}, {5, 8}, {8}]
    err = capsys.readouterr().err
    assert "jobs recovered at start: queued [1], deferred [5, 8]" in err
    assert "job recovery retried skipped: Transient: still down" in err
    assert "jobs recovered retried: queued [5], deferred [8]" in err and "closed [8]" in err
