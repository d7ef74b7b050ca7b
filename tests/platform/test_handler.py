"""The worker daemon's offer pipeline against an in-process chain and an on-disk store:
accept -> train -> upload manifest -> submitOutcome, idempotence, resume, capacity (jobs and
memory), failed jobs releasing the worker, store down."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import torch

from backend.chain.platform import OfferState, cid_commitment
from backend.store import IpfsRpcStore, NotFound, StoreUnavailable
from backend.store.bundle import MODEL_FILES, pull_model, read_bundle
from backend.store.sealed import public_key_hex, pull_model_with_key
from workers.daemon.handler import OfferHandler, Transient
from workers.mdrl.modelio import load_model
from workers.mdrl.resources import estimate
from workers.mdrl.trainingspec import TrainingSpec

from .helpers import TINY_SPEC, deploy, post_task, register

torch.set_num_threads(1)


def handler_for(p, address: str, store, tmp_path: Path, **kw) -> OfferHandler:
    account = p.chain._keys[address]
    return OfferHandler(
        account=account, platform=p, store=store, data_dir=tmp_path / "w" / address, **kw
    )


def test_offer_is_trained_uploaded_as_manifest_and_submitted(env, tmp_path: Path) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    assert len(offered) == 1
    points = []
    h = handler_for(p, offered[0], store, tmp_path)
    h._post_progress = lambda tid, point: points.append(point)  # type: ignore[method-assign]
    out = h.handle(task_id, offered[0].lower())
    assert out["status"] == "submitted"
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.SUBMITTED
    ev = p.tmc.contract.events.OutcomeSubmitted().get_logs(from_block=0)
    assert [e["args"]["cid"] for e in ev] == [out["cid"]]
    # live progress: one point per update with growing steps up to the budget
    steps = [pt["step"] for pt in points]
    assert len(steps) >= 3 and steps == sorted(set(steps)) and steps[-1] >= 1900
    assert not any("guided_share" in pt for pt in points)  # no experts, no guided episodes
    # the on-chain CID is a manifest whose two files make a loadable model
    assert sorted(read_bundle(store, out["cid"])) == sorted(MODEL_FILES)
    policy = load_model(pull_model(store, out["cid"], tmp_path / "pulled"))
    assert policy.card["env"]["rows"] == 6
    # idempotent: handling the same offer again sends no transaction
    block = p.chain.w3.eth.block_number
    again = h.handle(task_id, offered[0])
    assert again["status"] == "submitted" and again["cid"] == out["cid"]
    assert p.chain.w3.eth.block_number == block


def test_the_outcome_cid_is_committed_before_anyone_can_read_it(
    env, tmp_path: Path, monkeypatch
) -> None:
    """Commit-reveal: the daemon commits the bundle's CID on chain while the store does not
    hold it yet (so nobody can copy it first), publishes, then reveals it in a later block."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered[0], store, tmp_path)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    seen: list[tuple[str, bool]] = []
    real = p.tmc.commit_cid

    def commit(sender: str, cid: str):
        try:
            store.get(cid)
            readable = True
        except NotFound:
            readable = False
        seen.append((cid, readable))
        return real(sender, cid)

    monkeypatch.setattr(p.tmc, "commit_cid", commit)
    out = h.handle(task_id, offered[0])
    assert out["status"] == "submitted"
    assert seen == [(out["cid"], False)], "committed once, before the store held the manifest"
    committed = p.tmc.contract.events.CidCommitted().get_logs(from_block=0)
    submitted = p.tmc.contract.events.OutcomeSubmitted().get_logs(from_block=0)
    assert committed[-1]["blockNumber"] < submitted[-1]["blockNumber"]
    assert committed[-1]["args"]["commitment"] == cid_commitment(out["cid"], offered[0])


@pytest.mark.parametrize("sealed", [False, True])
def test_a_store_outage_after_the_commitment_keeps_its_priority(
    env, tmp_path: Path, monkeypatch, sealed: bool
) -> None:
    """The store fails between the commitment and the upload: the job is retried (Transient),
    commits the same CID again (no second commitment: the first block stands) and submits.
    Also for an outcome sealed to the requester, which is encrypted with a fresh key: the
    retry publishes the bundle staged before the commitment instead of sealing anew."""
    from backend.store.staged import StagedUpload

    p, actors, store = env
    key = public_key_hex(bytes(p.chain._keys[actors.requester].key))
    spec = {**TINY_SPEC, "outcome_key": key} if sealed else TINY_SPEC
    task_id, offered, _ = post_task(p, store, actors.requester, spec=spec)
    h = handler_for(p, offered[0], store, tmp_path)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    real = StagedUpload.publish

    def down(self, store):  # noqa: ANN001 - the store the daemon passes
        raise StoreUnavailable("http://127.0.0.1:5001", "ipfs node down")

    monkeypatch.setattr(StagedUpload, "publish", down)
    with pytest.raises(Transient, match="ipfs node down"):
        h.handle(task_id, offered[0])
    first = p.tmc.contract.events.CidCommitted().get_logs(from_block=0)
    assert len(first) == 1
    monkeypatch.setattr(StagedUpload, "publish", real)
    out = h.handle(task_id, offered[0])
    assert out["status"] == "submitted"
    assert p.tmc.contract.events.CidCommitted().get_logs(from_block=0) == first
    assert first[0]["args"]["commitment"] == cid_commitment(out["cid"], offered[0])
    assert not (h.job_dir(task_id) / "outbox").exists()  # published: not kept twice


def test_a_crashed_job_resumes_from_its_checkpoint(env, tmp_path: Path) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered[0], store, tmp_path, checkpoint_every=1)

    class Crash(BaseException):  # the process being stopped (SystemExit-like), not a job error
        pass

    def crash_at_update_3(tid: int, point: dict) -> None:
        if point.get("update") == 3:
            raise Crash()

    h._post_progress = crash_at_update_3  # type: ignore[method-assign]
    with pytest.raises(Crash):
        h.handle(task_id, offered[0])
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.ACCEPTED
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    out = h.handle(task_id, offered[0])
    assert out["status"] == "submitted"
    state = json.loads((h.job_dir(task_id) / "state.json").read_text())
    # the checkpoint of update 2 (not 3: it crashed before checkpointing) was the start point
    assert state["resumed_from_step"] == 2 * TrainingSpec.from_dict(TINY_SPEC).ppo.batch_steps


def test_declines_when_at_capacity(env, tmp_path: Path) -> None:
    p, actors, store = env
    t1, offered1, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered1[0], store, tmp_path)
    p.tmc.transact("acceptOffer", t1, sender=offered1[0])
    h._save(t1, phase="accepted")  # a job in progress
    # the same worker is offered a second task (it is the only candidate left with capacity)
    t2, offered2, _ = post_task(p, store, actors.requester, num_workers=3)
    assert offered1[0] in offered2
    out = h.handle(t2, offered1[0])
    assert out["status"] == "declined" and out["reason"] == "at capacity"
    assert p.tmc.offer(t2, offered1[0])["state"] == OfferState.DECLINED


def test_a_job_the_chain_no_longer_holds_releases_its_capacity(env, tmp_path: Path) -> None:
    """A job left "accepted" on disk whose offer the chain never accepted (or a task cancelled
    or past its deadline) must not keep the worker at capacity forever."""
    p, actors, store = env
    t1, offered1, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered1[0], store, tmp_path)
    h._save(t1, phase="accepted")  # on disk only: the offer on chain is still just offered
    t2, offered2, _ = post_task(p, store, actors.requester, num_workers=3)
    assert offered1[0] in offered2
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    assert h.handle(t2, offered1[0])["status"] == "submitted"
    assert h._state(t1)["phase"] == "closed"


def test_a_task_id_of_another_deployment_is_trained_afresh(env, tmp_path: Path) -> None:
    """Task 1 of a new deployment (a restarted dev chain counts from 1 again) must not receive
    the model trained for task 1 of the old one, even in the same worker directory."""
    p, actors, store = env
    spec_a = {**TINY_SPEC, "seed": 1}
    t_a, offered_a, _ = post_task(p, store, actors.requester, spec=spec_a)
    h_a = handler_for(p, offered_a[0], store, tmp_path)
    h_a._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    cid_a = h_a.handle(t_a, offered_a[0])["cid"]

    q = deploy(p.chain)  # another deployment: same task ids, other identity
    register(q, actors.requester, actors.workers)
    t_b, offered_b, _ = post_task(q, store, actors.requester, spec={**TINY_SPEC, "seed": 2})
    assert t_b == t_a and q.identity != p.identity
    h_b = handler_for(q, offered_b[0], store, tmp_path)
    assert offered_b == offered_a  # the same worker, so the same worker directory
    h_b._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    out = h_b.handle(t_b, offered_b[0])
    assert out["status"] == "submitted" and out["cid"] != cid_a
    card = load_model(pull_model(store, out["cid"], tmp_path / "b")).card
    assert card["training"]["run"]["seed"] == 2


def test_bad_spec_is_declined_naming_the_field(env, tmp_path: Path) -> None:
    p, actors, store = env
    bad = {"env": {"rows": 6, "cols": 6, "agents": 2}, "budget": {"steps": -5}}
    task_id, offered, _ = post_task(p, store, actors.requester, spec=bad)
    out = handler_for(p, offered[0], store, tmp_path).handle(task_id, offered[0])
    assert out["status"] == "declined" and "budget.steps" in out["reason"]


def test_a_sealed_outcome_goes_to_the_requester_only(env, tmp_path: Path) -> None:
    """``outcome_key``: the worker checks the key is the requester's on chain (the gateway's
    check can be bypassed by a direct addTask), seals the weights to it and submits the
    plaintext bundle's CID; publishing uploads the weights once the worker shares."""
    p, actors, store = env
    stranger = p.chain._keys[p.chain.accounts[6]]
    misaddressed = {**TINY_SPEC, "outcome_key": public_key_hex(bytes(stranger.key))}
    task_id, offered, _ = post_task(p, store, actors.requester, spec=misaddressed)
    out = handler_for(p, offered[0], store, tmp_path).handle(task_id, offered[0])
    assert out["status"] == "declined" and "not to the task's requester" in out["reason"]

    requester = p.chain._keys[actors.requester]
    sealed = {**TINY_SPEC, "outcome_key": public_key_hex(bytes(requester.key))}
    task_id, offered, _ = post_task(p, store, actors.requester, spec=sealed)
    h = handler_for(p, offered[0], store, tmp_path)
    out = h.handle(task_id, offered[0])
    assert out["status"] == "submitted"
    with pytest.raises(NotFound):  # anyone reading the chain: the card, not the weights
        pull_model(store, out["cid"], tmp_path / "anyone")
    mine = pull_model_with_key(store, out["cid"], tmp_path / "mine", bytes(requester.key))
    assert load_model(mine).card["env"]["rows"] == 6
    # sharing it before the requester accepted it publishes nothing (pending, or rejected)
    with pytest.raises(LookupError, match="has not accepted this outcome"):
        h.publish_outcome(task_id)
    with pytest.raises(NotFound):
        pull_model(store, out["cid"], tmp_path / "still-sealed")
    p.tmc.transact("reviewOutcome", task_id, offered[0], 4, True, sender=actors.requester)
    published = h.publish_outcome(task_id)
    assert published["cid"] == out["cid"] and published["env"]["rows"] == 6
    assert (pull_model(store, out["cid"], tmp_path / "now") / "model.safetensors").read_bytes() == (
        mine / "model.safetensors"
    ).read_bytes()
    with pytest.raises(LookupError, match="submitted no outcome"):
        h.publish_outcome(task_id + 100)


KEEP_BEST_SPEC = {**TINY_SPEC, "selection": {"keep_best": "time", "eval_every": 1}}


def submitted(env, tmp_path: Path, spec: dict) -> tuple[OfferHandler, int, dict]:
    """Post ``spec``; its first offeree trains and submits it (progress posts dropped)."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester, spec=spec)
    h = handler_for(p, offered[0], store, tmp_path)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    out = h.handle(task_id, offered[0])
    assert out["status"] == "submitted"
    return h, task_id, out


def test_selection_keep_best_delivers_the_best_evaluated_policy(env, tmp_path: Path) -> None:
    """``selection.keep_best``: greedy evaluations every ``eval_every`` updates; the outcome
    (submitted and published) is the policy with the shortest evaluation, not the last one."""
    store = env[2]
    h, task_id, out = submitted(env, tmp_path, KEEP_BEST_SPEC)
    run = h.job_dir(task_id) / "run"
    with (run / "metrics.csv").open() as f:
        rows = [r for r in csv.DictReader(f) if r["eval_time"] not in ("", "nan")]
    updates = int(rows[-1]["update"])
    assert [int(r["update"]) for r in rows] == list(range(1, updates + 1))  # every update
    best = min(rows, key=lambda r: (float(r["eval_time"]), float(r["eval_cost"]), int(r["update"])))
    pulled = pull_model(store, out["cid"], tmp_path / "pulled")
    card = load_model(pulled).card
    selected = card["training"]["selected"]
    assert selected["by"] == "time" and selected["update"] == int(best["update"])
    assert card["metrics"]["eval_time"] == pytest.approx(float(best["eval_time"]), abs=1e-4)
    assert card["training"]["updates"] == int(best["update"]) and updates > 1
    assert card["curve"], "the delivered model's card carries the run's training curve"
    delivered = (pulled / "model.safetensors").read_bytes()
    assert delivered == (run / "best" / "model.safetensors").read_bytes()
    if int(best["update"]) != updates:  # the last policy differs: it is not what was sent
        assert delivered != (run / "model" / "model.safetensors").read_bytes()
    p, actors, _ = env
    p.tmc.transact("reviewOutcome", task_id, h.address, 4, True, sender=actors.requester)
    assert h.publish_outcome(task_id)["cid"] == out["cid"]


def test_a_crashed_keep_best_job_delivers_what_an_uninterrupted_one_does(
    env, tmp_path: Path
) -> None:
    """The kept policy survives a crash: the checkpoint carries it, and the resumed job submits
    the same weights as a job never stopped (same spec, seed and budget)."""
    p, actors, store = env
    spec = {**TINY_SPEC, "selection": {"keep_best": "cost", "eval_every": 1}}

    class Crash(BaseException):
        pass

    def crash_at_update_4(tid: int, point: dict) -> None:
        if point.get("update") == 4:
            raise Crash()

    delivered = []
    for crash in (False, True):
        task_id, offered, _ = post_task(p, store, actors.requester, spec=spec)
        h = handler_for(p, offered[0], store, tmp_path / str(crash), checkpoint_every=1)
        if crash:
            h._post_progress = crash_at_update_4  # type: ignore[method-assign]
            with pytest.raises(Crash):
                h.handle(task_id, offered[0])
        h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
        out = h.handle(task_id, offered[0])
        assert out["status"] == "submitted"
        model = pull_model(store, out["cid"], tmp_path / f"pulled-{crash}")
        card = load_model(model).card
        delivered.append(((model / "model.safetensors").read_bytes(), card["training"]["selected"]))
    state = json.loads((h.job_dir(task_id) / "state.json").read_text())
    assert state["resumed_from_step"] > 0
    (weights, selected), (weights_crashed, selected_crashed) = delivered
    assert weights_crashed == weights
    assert {k: selected_crashed[k] for k in ("by", "update", "global_step", "eval_cost")} == {
        k: selected[k] for k in ("by", "update", "global_step", "eval_cost")
    }


def test_drlaas_train_task_trains_what_the_worker_delivers(env, tmp_path: Path) -> None:
    """One code path: `drlaas train --task SPEC` on a laptop gives the weights a worker
    submits for that spec (same parser, run config and trainer), kept policy included."""
    from safetensors.torch import load_file
    from typer.testing import CliRunner

    from drlaas.cli import app

    store = env[2]
    _, _, out = submitted(env, tmp_path, KEEP_BEST_SPEC)
    worker = pull_model(store, out["cid"], tmp_path / "worker")

    doc = tmp_path / "task.json"
    doc.write_text(json.dumps(TrainingSpec.from_dict(KEEP_BEST_SPEC).to_dict()))
    res = CliRunner().invoke(app, ["train", "--task", str(doc), "--out", str(tmp_path / "local"),
                                   "--no-progress", "--no-tensorboard"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output.strip().splitlines()[-1])
    assert summary["env_steps"] == TINY_SPEC["budget"]["steps"]
    local = Path(summary["best"])
    mine = load_file(local / "model.safetensors")
    theirs = load_file(worker / "model.safetensors")
    assert mine.keys() == theirs.keys()
    assert all(torch.equal(mine[k], theirs[k]) for k in mine)
    ours, theirs_card = load_model(local).card, load_model(worker).card
    same = ("by", "update", "global_step", "eval_time", "eval_cost", "eval_success")
    assert {k: ours["training"]["selected"][k] for k in same} == {
        k: theirs_card["training"]["selected"][k] for k in same
    }
    # the kept policy's card gives its own training time, not the whole run's
    assert 0 < ours["training"]["wall_time_s"] <= json.loads(
        (local.parent / "model" / "model.json").read_text()
    )["training"]["wall_time_s"]


def test_drlaas_train_task_refuses_what_it_cannot_train_here(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from drlaas.cli import app

    cid = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
    cases = {
        "bad": ({**TINY_SPEC, "env": {"rows": 1}}, [], "env.rows"),
        "cid": ({**TINY_SPEC, "experts": [cid]}, [], "cannot fetch it from the gateway"),
        "mixed": (TINY_SPEC, ["--experts", "oracle"], "drop --experts"),
    }
    for name, (spec, extra, msg) in cases.items():
        doc = tmp_path / f"{name}.json"
        doc.write_text(json.dumps(spec))
        out = tmp_path / f"run-{name}"
        res = CliRunner().invoke(app, ["train", "--task", str(doc), "--out", str(out), *extra],
                                 env={"DRLAAS_GATEWAY": "http://127.0.0.1:9",
                                      "DRLAAS_CACHE": str(tmp_path / "cache")})
        text = " ".join(res.output.replace("│", " ").split())
        assert res.exit_code == 2 and msg in text, (name, res.output)
        assert not out.exists()  # refused before anything was written


def test_store_down_is_a_clear_transient_error_then_the_retry_completes(
    env, tmp_path: Path
) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    down = IpfsRpcStore("http://127.0.0.1:9", retries=0, timeout=2)  # discard port: refused
    h = handler_for(p, offered[0], down, tmp_path)
    with pytest.raises(Transient) as info:
        h.handle(task_id, offered[0])
    assert "127.0.0.1:9" in str(info.value) and "unavailable" in str(info.value)
    assert isinstance(info.value.__cause__, StoreUnavailable)
    # nothing was accepted while the spec could not be read; the retry with the store back works
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.OFFERED
    h.store = store
    assert h.handle(task_id, offered[0])["status"] == "submitted"


def test_a_spec_beyond_the_workers_memory_is_declined_without_allocating(
    env, tmp_path: Path
) -> None:
    p, actors, store = env
    # 16 agents on 64 x 64 in 4,096 envs: ~27 GiB of rollout, observers and maps
    brick = {
        "env": {"rows": 64, "cols": 64, "agents": 16},
        "observation": {"kind": "dmtl"},
        "algorithm": {"ppo": {"num_envs": 4096, "horizon": 256}},
        "budget": {"steps": 1000},
    }
    assert estimate(TrainingSpec.from_dict(brick)).memory_bytes > 16 * 2**30
    task_id, offered, _ = post_task(p, store, actors.requester, spec=brick)
    h = handler_for(p, offered[0], store, tmp_path, memory_bytes=16 * 2**30)
    out = h.handle(task_id, offered[0])
    assert out["status"] == "declined" and out["reason"].startswith("spec_exceeds_worker_memory")
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED
    # the tiny spec fits a normal worker, but not one with a byte less than its estimate
    need = estimate(TrainingSpec.from_dict(TINY_SPEC)).memory_bytes
    t2, offered2, _ = post_task(p, store, actors.requester)
    small = handler_for(p, offered2[0], store, tmp_path / "small", memory_bytes=need - 1)
    out = small.handle(t2, offered2[0])
    assert out["status"] == "declined" and "spec_exceeds_worker_memory" in out["reason"]


def test_a_failing_job_is_given_back_on_chain_and_releases_the_worker(
    env, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester, duration=1_800)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)

    def broken_training(*args, **kwargs):
        raise FloatingPointError("loss is NaN")

    monkeypatch.setattr("workers.daemon.job.run_job", broken_training)
    out = h.handle(task_id, worker)
    assert out["status"] == "failed" and "FloatingPointError: loss is NaN" in out["reason"]
    # given back at once (TMC abandonOffer), not held until the deadline
    assert out["offer"] == "failed"
    assert p.tmc.offer(task_id, worker)["state"] == OfferState.FAILED
    failed = p.tmc.contract.events.OfferFailed().get_logs(from_block=0)
    assert [(e["args"]["taskId"], e["args"]["worker"]) for e in failed] == [(task_id, worker)]
    assert p.tmc.task(task_id)["filled"] == 0
    assert h.active_jobs(exclude=0) == []  # capacity released at once
    # the slot is open again: the requester re-recruits, and the failed worker is not offered
    again, _ = p.tmc.allocate(actors.requester, task_id)
    assert again and worker not in again
    # handling the old job again changes nothing on chain
    block = p.chain.w3.eth.block_number
    assert h.handle(task_id, worker)["status"] == "offer failed"
    assert p.chain.w3.eth.block_number == block
    # the same worker takes (and trains) its next offer instead of declining it forever
    monkeypatch.undo()
    t2, offered2, _ = post_task(p, store, actors.requester, num_workers=3)
    assert worker in offered2
    assert h.handle(t2, worker)["status"] == "submitted"


class Killed(BaseException):
    """The training process dying (killed for memory): not an exception a job handles."""


def test_a_job_that_dies_at_every_start_is_given_back_not_redelivered_forever(
    env, tmp_path: Path
) -> None:
    from workers.daemon.handler import MAX_STARTS_WITHOUT_PROGRESS

    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path, checkpoint_every=1)

    def die(tid: int, step: int) -> None:  # dies before its first update, every time
        raise Killed()

    h.on_first_step = die
    for _ in range(MAX_STARTS_WITHOUT_PROGRESS):
        with pytest.raises(Killed):
            h.handle(task_id, worker)
        assert p.tmc.offer(task_id, worker)["state"] == OfferState.ACCEPTED
    out = h.handle(task_id, worker)  # the next delivery does not start it again
    assert out["status"] == "failed" and out["offer"] == "failed"
    assert f"started {MAX_STARTS_WITHOUT_PROGRESS} times" in out["reason"]
    assert p.tmc.offer(task_id, worker)["state"] == OfferState.FAILED
    assert not (h.job_dir(task_id) / "run" / "checkpoint").exists()  # pruned


def test_a_job_killed_often_but_moving_on_each_time_is_finished(env, tmp_path: Path) -> None:
    """Only starts that get no further count: a job whose checkpoint moves between kills (here
    at updates 2, 3 and 4 of 5, one more than the limit of starts) is trained to the end."""
    from workers.daemon.handler import MAX_STARTS_WITHOUT_PROGRESS

    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered[0], store, tmp_path, checkpoint_every=1)
    kills = list(range(2, 2 + MAX_STARTS_WITHOUT_PROGRESS))  # the progress point of update k

    def kill(tid: int, point: dict) -> None:
        if kills and point["update"] == kills[0]:
            kills.pop(0)
            raise Killed()

    h._post_progress = kill  # type: ignore[method-assign]
    for _ in range(MAX_STARTS_WITHOUT_PROGRESS):
        with pytest.raises(Killed):
            h.handle(task_id, offered[0])
    out = h.handle(task_id, offered[0])
    assert out["status"] == "submitted", out
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.SUBMITTED
    # the finished job keeps its model (publish reads it), not its checkpoint
    assert (h.job_dir(task_id) / "run" / "model" / "model.json").is_file()
    assert not (h.job_dir(task_id) / "run" / "checkpoint").exists()


def test_a_job_killed_after_training_before_its_record_is_not_trained_again(
    env, tmp_path: Path, monkeypatch
) -> None:
    """Training that ran to the end is not redone when the process dies before the handler
    records it: the next start uploads and submits the model it finished, with its curve."""
    from workers.daemon import job as jobs

    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered[0], store, tmp_path)
    save = h._save

    def killed_at_the_record(tid: int, **changes):
        if changes.get("phase") == "trained":
            raise Killed()
        return save(tid, **changes)

    h._save = killed_at_the_record  # type: ignore[method-assign]
    with pytest.raises(Killed):
        h.handle(task_id, offered[0])
    h._save = save  # type: ignore[method-assign]
    model = h.job_dir(task_id) / "run" / "model"
    card = (model / "model.json").read_text()
    assert json.loads(card).get("curve")
    runs = []
    real = jobs.run_job
    monkeypatch.setattr(jobs, "run_job", lambda *a, **kw: runs.append(a) or real(*a, **kw))
    out = h.handle(task_id, offered[0])
    assert out["status"] == "submitted" and runs == []
    assert (model / "model.json").read_text() == card
    assert read_bundle(store, out["cid"])["model.json"][0] == store.add(card.encode())


def test_recover_at_start_reconciles_job_directories_with_the_chain(env, tmp_path: Path) -> None:
    p, actors, store = env
    # three tasks offered to every worker; one worker's daemon left them in different states
    t_failed, offered, _ = post_task(p, store, actors.requester, num_workers=3)
    worker = offered[0]
    t_in_hand, o2, _ = post_task(p, store, actors.requester, num_workers=3)
    t_gone, o3, _ = post_task(p, store, actors.requester, num_workers=3)
    assert worker in o2 and worker in o3
    h = handler_for(p, worker, store, tmp_path)
    for tid in (t_failed, t_in_hand):
        p.tmc.transact("acceptOffer", tid, sender=worker)
    # failed while the node was down: abandonOffer never reached the chain
    h._save(t_failed, phase="failed", reason="gave up after 8 retries: node down")
    h._save(t_in_hand, phase="trained", model="model")  # its message lost with the broker
    h._save(t_gone, phase="accepted")  # on disk only: the chain never saw the acceptance
    (h.job_dir(t_failed) / "run" / "checkpoint").mkdir(parents=True)
    (h.job_dir(t_in_hand) / "run" / "checkpoint").mkdir(parents=True)
    queued: list[tuple[int, str]] = []
    done = h.recover(lambda tid, w: queued.append((tid, w)))
    assert done == {"reported": [t_failed], "queued": [t_in_hand], "submitted": [],
                    "closed": [t_gone], "pruned": [t_failed], "deferred": []}
    assert queued == [(t_in_hand, worker)]
    assert p.tmc.offer(t_failed, worker)["state"] == OfferState.FAILED
    assert p.tmc.offer(t_in_hand, worker)["state"] == OfferState.ACCEPTED
    assert h._state(t_gone)["phase"] == "closed"
    assert (h.job_dir(t_in_hand) / "run" / "checkpoint").is_dir()  # still needed to resume
    assert not (h.job_dir(t_failed) / "run" / "checkpoint").exists()
    # a second start finds nothing left to do but the job in hand
    block = p.chain.w3.eth.block_number
    assert h.recover(None) == {"reported": [], "queued": [t_in_hand], "submitted": [],
                               "closed": [], "pruned": [], "deferred": []}
    assert p.chain.w3.eth.block_number == block


def test_recover_defers_what_needs_a_node_that_is_down_and_goes_on_with_the_rest(
    env, tmp_path: Path
) -> None:
    """Recovery at start is per job: once the node fails a call, the other jobs that need the
    chain are deferred without waiting on it again, while finished jobs are still pruned; a
    job whose own reconciliation fails is deferred and the next one is still reconciled; a
    retry with ``only`` then queues exactly the deferred jobs."""
    p, actors, store = env
    tasks = [post_task(p, store, actors.requester, num_workers=3) for _ in range(2)]
    worker = tasks[0][1][0]
    t_a, t_b = (t for t, _, _ in tasks)
    h = handler_for(p, worker, store, tmp_path)
    for tid in (t_a, t_b):
        p.tmc.transact("acceptOffer", tid, sender=worker)
        h._save(tid, phase="trained", model="model")
    t_done = t_b + 1  # a finished job of an earlier task with its checkpoint still on disk
    h._save(t_done, phase="submitted", cid="bafy")
    (h.job_dir(t_done) / "run" / "checkpoint").mkdir(parents=True)
    settle, tried = h._settle, []

    def node_down(tid: int, st: dict) -> None:
        tried.append(tid)
        raise Transient("chain node unreachable during reading the offer: refused")

    h._settle = node_down  # type: ignore[method-assign]
    queued: list[int] = []
    done = h.recover(lambda tid, w: queued.append(tid))
    assert done["deferred"] == [t_a, t_b] and tried == [t_a]  # not asked again for t_b
    assert done["pruned"] == [t_done] and queued == []
    assert not (h.job_dir(t_done) / "run" / "checkpoint").exists()

    def damaged(tid: int, st: dict) -> str | None:
        if tid == t_a:
            raise KeyError("deadline")
        return settle(tid, st)

    h._settle = damaged  # type: ignore[method-assign]
    done = h.recover(lambda tid, w: queued.append(tid), only={t_a, t_b})
    assert done["deferred"] == [t_a] and done["queued"] == [t_b] and queued == [t_b]
    h._settle = settle  # type: ignore[method-assign]
    done = h.recover(lambda tid, w: queued.append(tid), only={t_a})
    assert done["queued"] == [t_a] and done["deferred"] == [] and queued == [t_b, t_a]
    assert h._state(t_a)["phase"] == "trained"  # nothing lost while deferred


def test_walls_that_leave_the_team_no_room_are_declined_not_accepted(env, tmp_path: Path) -> None:
    p, actors, store = env
    # within every bound of the spec (4 walls on a 4 x 4 grid), yet 8 agents never fit
    cramped = {**TINY_SPEC, "env": {"rows": 4, "cols": 4, "agents": 8, "walls": [4, 4]}}
    task_id, offered, _ = post_task(p, store, actors.requester, spec=cramped)
    out = handler_for(p, offered[0], store, tmp_path).handle(task_id, offered[0])
    assert out["status"] == "declined" and "of the wall layouts" in out["reason"], out
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED


def test_a_node_answering_5xx_or_mining_late_is_retried_never_a_failed_job(
    env, tmp_path: Path, monkeypatch
) -> None:
    """A 503 from the node (or a proxy before it) and a receipt wait that times out are the
    node's trouble, not the job's: Transient (the Celery job retries), never a trained model
    thrown away with abandonOffer. A submitOutcome mined after its receipt wait gave up is
    recorded as submitted on the next delivery."""
    import requests
    from web3.exceptions import TimeExhausted

    from workers.daemon.handler import node_unreachable

    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    real = p.tmc.transact
    busy = requests.Response()
    busy.status_code = 503
    calls = {"503": 0}

    def flaky(fn, *args, **kw):
        if fn == "submitOutcome" and calls["503"] == 0:
            calls["503"] += 1
            raise requests.HTTPError("503 Service Unavailable", response=busy)
        if fn == "submitOutcome":
            real(fn, *args, **kw)  # mined, but the receipt wait gives up first
            raise TimeExhausted("not in the chain after 120 seconds")
        return real(fn, *args, **kw)

    monkeypatch.setattr(p.tmc, "transact", flaky)
    with pytest.raises(Transient, match="submitOutcome"):
        h.handle(task_id, worker)
    assert h._state(task_id)["phase"] == "uploaded"
    with pytest.raises(Transient, match="submitOutcome"):
        h.handle(task_id, worker)
    monkeypatch.undo()
    assert p.tmc.offer(task_id, worker)["state"] == OfferState.SUBMITTED
    out = h.handle(task_id, worker)
    assert out["status"] == "submitted" and h._state(task_id)["phase"] == "submitted"
    p.tmc.transact("reviewOutcome", task_id, worker, 4, True, sender=actors.requester)
    assert h.publish_outcome(task_id)["cid"] == out["cid"]
    assert not p.tmc.contract.events.OfferFailed().get_logs(from_block=0)
    bad_request = requests.Response()
    bad_request.status_code = 400
    assert not node_unreachable(requests.HTTPError("400", response=bad_request))


def test_a_submit_mined_by_an_earlier_try_is_recorded_not_failed(
    env, tmp_path: Path, monkeypatch
) -> None:
    """The retry of a submitOutcome whose first try was mined meanwhile reverts; the job reads
    the chain and records the outcome as submitted instead of failing it."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    real = p.tmc.transact

    def twice(fn, *args, **kw):
        if fn == "submitOutcome":
            real(fn, *args, **kw)  # the earlier try, mined late
        return real(fn, *args, **kw)

    monkeypatch.setattr(p.tmc, "transact", twice)
    out = h.handle(task_id, worker)
    monkeypatch.undo()
    assert out["status"] == "submitted" and h._state(task_id)["phase"] == "submitted"
    assert p.tmc.offer(task_id, worker)["state"] == OfferState.SUBMITTED


def test_store_outages_while_fetching_models_are_not_starts_that_died(
    env, tmp_path: Path
) -> None:
    from workers.daemon.handler import MAX_STARTS_WITHOUT_PROGRESS

    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered[0], store, tmp_path)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    real = h._fetch_experts
    outages = [Transient("content store unavailable")] * (MAX_STARTS_WITHOUT_PROGRESS + 1)

    def fetch(tid, spec):
        if outages:
            raise outages.pop()
        return real(tid, spec)

    h._fetch_experts = fetch  # type: ignore[method-assign]
    for _ in range(MAX_STARTS_WITHOUT_PROGRESS + 1):
        with pytest.raises(Transient):
            h.handle(task_id, offered[0])
    assert h._state(task_id).get("starts_without_progress", 0) == 0
    assert h.handle(task_id, offered[0])["status"] == "submitted"


def test_recover_survives_damaged_job_directories_and_records_late_submits(
    env, tmp_path: Path
) -> None:
    """An unreadable state.json is set aside and the job rebuilt from the chain; a job killed
    between acceptOffer and its record, or between submitOutcome and its record, is seen;
    directory names that are not task ids as the daemon writes them are not jobs; a failure
    whose give-back the chain refused is not reported again at every start."""
    p, actors, store = env
    tasks = [post_task(p, store, actors.requester, num_workers=3) for _ in range(4)]
    worker = tasks[0][1][0]
    assert all(worker in offered for _, offered, _ in tasks)
    t_corrupt, t_accepting, t_submitted, t_refused = (t for t, _, _ in tasks)
    h = handler_for(p, worker, store, tmp_path)
    for tid in (t_corrupt, t_accepting, t_submitted):
        p.tmc.transact("acceptOffer", tid, sender=worker)
    h._save(t_corrupt, phase="trained")
    (h.job_dir(t_corrupt) / "state.json").write_text("")  # a disk fault
    h._save(t_accepting, phase="accepting")  # killed right after the acceptOffer transaction
    # killed after submitOutcome, before the record: the disk says uploaded
    cid = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
    h._save(t_submitted, phase="uploaded", cid=cid)
    p.tmc.submit_outcome(worker, t_submitted, cid)
    # never accepted on chain: abandonOffer is refused; the refusal is recorded once
    h._save(t_refused, phase="failed", reason="broken")
    assert h._report_failure(t_refused)["offer"].startswith("not abandoned")
    for odd in ("01", "\u00b2", "x"):  # not task ids as job_dir writes them
        (h._jobs_root / odd).mkdir()
        (h._jobs_root / odd / "state.json").write_text(json.dumps({"phase": "failed"}))
    queued: list[int] = []
    done = h.recover(lambda tid, w: queued.append(tid))
    assert done == {"reported": [], "queued": [t_corrupt, t_accepting], "submitted": [t_submitted],
                    "closed": [], "pruned": [], "deferred": []}
    assert queued == [t_corrupt, t_accepting]
    assert list(h.job_dir(t_corrupt).glob("state.json.unreadable-*"))
    assert h._state(t_corrupt)["phase"] == "accepted"
    assert h._state(t_submitted)["phase"] == "submitted"
    assert p.tmc.offer(t_refused, worker)["state"] == OfferState.OFFERED
    # the job in hand counts against capacity; the offered-only one is not a job
    assert sorted(h.active_jobs(exclude=0)) == [t_corrupt, t_accepting]


def test_a_resumed_job_trains_for_the_time_left_not_the_time_already_spent(
    env, tmp_path: Path
) -> None:
    """Trainer budgets count the training time of earlier runs; a job resumed with less wall
    time left before its deadline than it already trained still trains for that time (its
    budget is the time so far plus the time left), and ends with its final evaluation."""
    from workers.daemon import job as jobs

    spec = TrainingSpec.from_dict({**TINY_SPEC, "budget": {"steps": 100_000, "minutes": 60}})
    job = tmp_path / "job"

    class Stop(BaseException):
        pass

    def stop_at_update_2(point: dict) -> None:
        if point["update"] == 2:
            raise Stop()

    with pytest.raises(Stop):
        jobs.run_job(spec, job, checkpoint_every=1, on_progress=stop_at_update_2)
    trainer = jobs.make_trainer(spec, job, minutes_left=0.5)
    assert trainer.elapsed > 0 and trainer.update_idx == 1
    assert trainer.run.minutes == pytest.approx(trainer.elapsed / 60 + 0.5)
    capped = jobs.make_trainer(spec, job, minutes_left=600)
    assert capped.run.minutes == 60  # within the spec's own budget


def test_a_spec_the_store_cannot_find_after_acceptance_is_retried_not_failed(
    env, tmp_path: Path, monkeypatch
) -> None:
    """A spec the store says it does not hold (NotFound; a node's find timeout is FindTimeout,
    retried: test_find_timeout.py). Before accepting, that is a decline; for a job already
    accepted (the worker read the spec then, e.g. redelivered after a restart) it is a
    Transient failure, retried, not the job failed on chain."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    h = handler_for(p, offered[0], store, tmp_path)
    real = store.get

    def lost(cid, *a, **kw):  # noqa: ANN001, ANN002, ANN003 - content nobody holds
        raise NotFound(str(cid), "not held by any node")

    monkeypatch.setattr(store, "get", lost)
    out = h.handle(task_id, offered[0])
    assert out["status"] == "declined" and "not held by any node" in out["reason"], out

    task_id, offered, _ = post_task(p, store, actors.requester, spec={**TINY_SPEC, "seed": 9})
    h = handler_for(p, offered[0], store, tmp_path)
    p.tmc.transact("acceptOffer", task_id, sender=offered[0])  # accepted, then restarted
    with pytest.raises(Transient, match="not held by any node"):
        h.handle(task_id, offered[0])
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.ACCEPTED
    monkeypatch.setattr(store, "get", real)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    assert h.handle(task_id, offered[0])["status"] == "submitted"
