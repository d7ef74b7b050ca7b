"""Expert models of MEDC jobs on the worker (workers/daemon/experts.py, job.py, handler.py):
fetched by CID and verified (tampered, oversize, pickled, bad-card bundles refused with an error
naming the CID), a job that cannot use its experts fails on chain, and a resumed MEDC job keeps
its selector (thesis Alg. 5.1)."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from backend.chain.client import Chain
from backend.chain.platform import OfferState
from backend.store import EmbeddedStore, StoreUnavailable
from backend.store.bundle import add_bundle, read_bundle, upload_model
from workers.daemon import job as jobs
from workers.daemon.experts import ExpertFetchError, fetch_experts, fetch_walls_cae
from workers.daemon.handler import OfferHandler
from workers.mdrl.trainingspec import TrainingSpec

from .helpers import TINY_SPEC, deploy, post_task, register

torch.set_num_threads(1)
EXPERT = Path(__file__).resolve().parents[2] / "models" / "odmtl-2a"  # window 5, fits 6x6


@pytest.fixture
def store(tmp_path: Path) -> EmbeddedStore:
    return EmbeddedStore(tmp_path / "ipfs")


def medc_spec(*cids: str, qos: tuple[float, ...] = (), rate: float = 0.5) -> TrainingSpec:
    experts = (
        [{"model": c, "qos": q} for c, q in zip(cids, qos, strict=True)] if qos else list(cids)
    )
    return TrainingSpec.from_dict(
        {**TINY_SPEC, "experts": experts, "algorithm": {"demonstration": {"rate": rate}}}
    )


def bundle(store: EmbeddedStore, **changes: bytes) -> str:
    files = {n: (EXPERT / n).read_bytes() for n in ("model.safetensors", "model.json")}
    return add_bundle(store, {**files, **changes})


def refused(store: EmbeddedStore, cid: str, tmp_path: Path, **kw) -> str:
    with pytest.raises(ExpertFetchError) as err:
        fetch_experts(store, [cid], tmp_path / "job", **kw)
    assert err.value.cid == cid and cid in str(err.value)
    assert not list((tmp_path / "job" / "experts").glob("*/model.json"))  # nothing kept
    return err.value.reason


def test_a_good_expert_is_verified_kept_and_not_fetched_again(store, tmp_path: Path) -> None:
    cid = upload_model(store, EXPERT)
    dirs = fetch_experts(store, [cid], tmp_path / "job")
    got = dirs[cid]
    assert got.parent == tmp_path / "job" / "experts"
    for name in ("model.safetensors", "model.json"):
        assert (got / name).read_bytes() == (EXPERT / name).read_bytes()

    class Down(EmbeddedStore):
        def _read_block(self, cid, max_bytes):  # noqa: ANN001
            raise StoreUnavailable("test", "down")

    # a restarted job finds its experts in the job directory: no fetch at all
    assert fetch_experts(Down(tmp_path / "ipfs"), [cid], tmp_path / "job") == dirs
    with pytest.raises(StoreUnavailable):  # a new job with the store down: retry later
        fetch_experts(Down(tmp_path / "ipfs"), [cid], tmp_path / "job2")


def test_tampered_bytes_are_refused(store, tmp_path: Path) -> None:
    cid = upload_model(store, EXPERT)
    weights_cid, _ = read_bundle(store, cid)["model.safetensors"]
    block = store.block_path(weights_cid)
    data = bytearray(block.read_bytes())
    data[100] ^= 0xFF
    block.write_bytes(bytes(data))
    assert "model.safetensors" in refused(store, cid, tmp_path)


def test_oversize_pickled_and_bad_card_bundles_are_refused(store, tmp_path: Path) -> None:
    good = upload_model(store, EXPERT)
    size = (EXPERT / "model.safetensors").stat().st_size
    assert "more than the bound" in refused(store, good, tmp_path, max_weights=size - 1)

    tensors = {k: v.numpy() for k, v in load_file(EXPERT / "model.safetensors").items()}
    pickled = bundle(store, **{"model.safetensors": pickle.dumps(tensors)})
    assert "pickle" in refused(store, pickled, tmp_path)
    zipped = bundle(store, **{"model.safetensors": b"PK\x03\x04" + b"\0" * 64})
    assert "zip archive" in refused(store, zipped, tmp_path)
    raw = (EXPERT / "model.safetensors").read_bytes()
    truncated = bundle(store, **{"model.safetensors": raw[:-8]})
    assert "not fully covered" in refused(store, truncated, tmp_path)  # the safetensors check

    card = json.loads((EXPERT / "model.json").read_text())
    wrong = bundle(store, **{"model.json": json.dumps({**card, "format": "other/1"}).encode()})
    assert "not a drlaas-model/1 card" in refused(store, wrong, tmp_path)
    not_json = bundle(store, **{"model.json": b"{not json"})
    assert "not JSON" in refused(store, not_json, tmp_path)
    bad_env = bundle(store, **{"model.json": json.dumps({**card, "env": {"rows": -1}}).encode()})
    assert "env.rows: must be in" in refused(store, bad_env, tmp_path)

    # an expert's card is bounded as a task spec is: a huge grid or window would exhaust the
    # worker's memory when the expert's observer is built, so it is refused naming the field
    huge = {**card, "env": {**card["env"], "rows": 100_000, "cols": 100_000}}
    assert "env.rows" in refused(store, bundle(store, **{"model.json": json.dumps(huge).encode()}),
                                 tmp_path)
    wide = {**card, "observation": {**card["observation"], "window": 10_001}}
    assert "observation.window" in refused(
        store, bundle(store, **{"model.json": json.dumps(wide).encode()}), tmp_path)
    crowd = {**card, "env": {**card["env"], "agents": 5_000}}
    assert "env.agents" in refused(
        store, bundle(store, **{"model.json": json.dumps(crowd).encode()}), tmp_path)

    extra = bundle(store, **{"run.py": b"print('hi')"})
    assert "exactly" in refused(store, extra, tmp_path)
    assert "not a model CID" in refused(store, "experts/mine", tmp_path)
    absent = store.key("bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy")
    assert "manifest" in refused(store, absent, tmp_path)


def test_a_resumed_medc_job_keeps_its_selector(store, tmp_path: Path) -> None:
    cid = upload_model(store, EXPERT)
    spec = medc_spec(cid, qos=(0.7,))

    def train(job: Path, crash_at: int | None = None) -> Path:
        def hook(point: dict) -> None:
            if point["update"] == crash_at:
                raise KeyboardInterrupt  # the worker killed after this update's checkpoint

        dirs = fetch_experts(store, spec.experts, job)
        return jobs.run_job(spec, job, checkpoint_every=1, on_progress=hook, experts=dirs)[0]

    straight = train(tmp_path / "a")
    with pytest.raises(KeyboardInterrupt):
        train(tmp_path / "b", crash_at=2)
    state = json.loads((jobs.run_dir(tmp_path / "b") / "checkpoint" / "state.json").read_text())
    assert state["selector"]["config"]["models"] == [cid]  # by CID, not by local path
    resumed = train(tmp_path / "b")
    card_a = json.loads((straight / "model.json").read_text())["training"]["experts"]
    card_b = json.loads((resumed / "model.json").read_text())["training"]["experts"]
    assert card_a == card_b  # episodes each expert guided, decisions, followed: one run
    assert card_a["experts"][0]["ref"] == cid and card_a["experts"][0]["qos"] == 0.7
    assert card_a["experts"][0]["episodes"] > 0 and card_a["own_episodes"] > 0
    wa, wb = load_file(straight / "model.safetensors"), load_file(resumed / "model.safetensors")
    assert all(torch.equal(wa[k], wb[k]) for k in wa)


def test_the_job_delivers_its_experts_trial_or_the_model_without_it(
    store, tmp_path: Path, monkeypatch, caplog
) -> None:
    """An expert-guided job's card carries the worker's trial of each expert on the task (the
    requester's evidence for its review); when the trial fails, the trained model is still
    delivered, without it."""
    import workers.mdrl.review as review

    cid = upload_model(store, EXPERT)
    spec = medc_spec(cid)
    dirs = fetch_experts(store, spec.experts, tmp_path / "a")
    model = jobs.run_job(spec, tmp_path / "a", experts=dirs)[0]
    trial = json.loads((model / "model.json").read_text())["training"]["experts"]["review"]
    assert trial == json.loads(json.dumps(review.review_experts([(cid, str(dirs[cid]))],
                                                                spec.env)))

    def broken(*args, **kwargs):
        raise RuntimeError("out of memory")

    monkeypatch.setattr(review, "review_experts", broken)
    dirs = fetch_experts(store, spec.experts, tmp_path / "b")
    model = jobs.run_job(spec, tmp_path / "b", experts=dirs)[0]
    card = json.loads((model / "model.json").read_text())
    assert "review" not in card["training"]["experts"] and card["training"]["experts"]["experts"]
    assert "no expert review in the card: RuntimeError: out of memory" in caplog.text
    assert (tmp_path / "b" / jobs.FINISHED_MARK).is_file()

    # a job that trained up to its deadline delivers without the trial, in time
    monkeypatch.undo()
    dirs = fetch_experts(store, spec.experts, tmp_path / "c")
    model = jobs.run_job(spec, tmp_path / "c", experts=dirs, minutes_left=0.02)[0]
    assert "review" not in json.loads((model / "model.json").read_text())["training"]["experts"]
    assert "no expert review in the card: the deadline is too near" in caplog.text


# -- the offer pipeline -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def chain() -> Chain:
    return Chain.embedded(accounts=6)


@pytest.fixture
def env(chain: Chain, store: EmbeddedStore):
    snap = chain.snapshot()
    p = deploy(chain)
    actors = register(p, chain.accounts[1], chain.accounts[2:3])
    yield p, actors
    chain.revert(snap)


def _bad_models(store: EmbeddedStore, tmp_path: Path) -> dict[str, tuple[dict, str]]:
    """{case: (task spec, what the decline must say)}: bundles whose manifest and card pass
    the card checks, with a defect only fetching and loading them shows."""
    from backend.store.bundle import BUNDLE_FORMAT, canonical_json
    from backend.store.dag import compute_cid

    weights, card = (EXPERT / "model.safetensors").read_bytes(), (EXPERT / "model.json")
    card_json = json.loads(card.read_text())

    def manifest(entry: dict) -> str:  # a bundle whose weights entry says what we want
        return store.add(canonical_json({"format": BUNDLE_FORMAT, "files": {
            "model.json": {"cid": store.add(card.read_bytes()), "size": card.stat().st_size},
            "model.safetensors": entry}}))

    local = walls_cae(tmp_path)
    cae_card = json.loads((local / "model.json").read_text())
    cae_weights = (local / "model.safetensors").read_bytes()

    def cae(card: dict) -> str:
        return add_bundle(store, {"model.safetensors": cae_weights,
                                  "model.json": json.dumps(card).encode()})

    shape = card_json | {"observation": card_json["observation"] | {"actor_shape": [1, 2, 3]}}
    no_digest = {k: v for k, v in cae_card.items() if k != "encoder_digest"}
    experts = {
        "pickled weights": (bundle(store, **{"model.safetensors": pickle.dumps({"w": [1.0]})}),
                            "model.safetensors is a pickle"),
        "weights not in the store": (manifest({"cid": compute_cid(weights + b" "),
                                               "size": len(weights) + 1}),
                                     "is not in the store"),
        "weights of another size": (manifest({"cid": store.add(weights), "size": 100}),
                                    "failed verification"),
        "a card's input shape the task cannot give": (
            bundle(store, **{"model.json": json.dumps(shape).encode()}),
            "the adapter builds inputs of shape (8, 5, 5)"),
        "a CAE card as an expert": (bundle(store, **{"model.json": json.dumps(
            card_json | {"kind": "cae"}).encode()}), "not a policy"),
    }
    cases = {k: ({**TINY_SPEC, "experts": [cid]}, why) for k, (cid, why) in experts.items()}
    cases["a walls CAE of another d"] = (cae_spec(cae(cae_card), d=32),
                                         "observation.walls_embedding_size = 32")
    cases["a walls CAE without its encoder digest"] = (cae_spec(cae(no_digest)),
                                                       "encoder_digest")
    cases["a walls CAE whose weights are not its card's"] = (
        cae_spec(cae(cae_card | {"embedding": 32}), d=32), "tensors the weights do not hold")
    return cases


def test_a_model_no_run_could_use_is_declined_before_acceptance(env, store, tmp_path) -> None:
    """Before it accepts, the worker fetches each expert and walls CAE, verified against its
    CID, and loads it as the job would: weights missing from the store, weights not as the
    manifest says, a pickle, a card whose input shape or embedding size contradicts the
    weights or the task. Each is a decline naming the CID, not an accepted job failed on
    chain (which lowers the worker's reputation, Eq. 18), and nothing of it stays on disk;
    the redelivered offer is not retried."""
    p, actors = env
    for case, (spec, why) in _bad_models(store, tmp_path).items():
        task_id, offered, _ = post_task(p, store, actors.requester, spec=spec)
        h = OfferHandler(account=p.chain._keys[offered[0]], platform=p, store=store,
                         data_dir=tmp_path / "w")
        out = h.handle(task_id, offered[0])
        assert out["status"] == "declined", (case, out)
        assert why in out["reason"] and "expert bafk" in out["reason"], (case, out["reason"])
        assert str(tmp_path) not in out["reason"], case  # the model named, not the worker's disk
        assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED, case
        job = h.job_dir(task_id)
        assert not (job / "experts").exists() and not (job / "cae").exists(), case
        assert h.handle(task_id, offered[0])["status"] == "offer declined", case


def test_the_models_checked_before_acceptance_are_not_fetched_again(
    env, store, tmp_path, monkeypatch
) -> None:
    """What the worker fetched and verified to decide is what the job trains with: after the
    offer is accepted nothing is read from the store again."""
    p, actors = env
    cid = upload_model(store, EXPERT)
    spec = {**TINY_SPEC, "experts": [cid], "budget": {"steps": 200}}
    task_id, offered, _ = post_task(p, store, actors.requester, spec=spec)
    h = OfferHandler(account=p.chain._keys[offered[0]], platform=p, store=store,
                     data_dir=tmp_path / "w")
    reads: list[str] = []
    real = store.get_to_file
    monkeypatch.setattr(store, "get_to_file", lambda c, *a, **k: (reads.append(
        h._state(task_id).get("phase", "")), real(c, *a, **k))[1])
    out = h.handle(task_id, offered[0])
    assert out["status"] == "submitted", out
    assert len(reads) >= 2 and set(reads) == {"offered"}, reads  # all before accepting


def test_an_expert_whose_card_no_worker_can_use_is_declined_not_failed(
    env, store, tmp_path
) -> None:
    """The worker reads each expert's manifest and card before it accepts: a card it cannot
    rebuild a model from (here one with no observation, which the gateway's bundle check lets
    through) or weights beyond its bound get the offer declined naming the CID, instead of a
    job failed on chain after acceptance (the worker's reputation would pay for the
    requester's choice). Nothing of the weights is fetched."""
    p, actors = env
    card = json.loads((EXPERT / "model.json").read_text())
    no_observation = bundle(store, **{"model.json": json.dumps(
        {"format": card["format"], "env": card["env"]}).encode()})
    h = OfferHandler(account=p.chain._keys[p.chain.accounts[2]], platform=p, store=store,
                     data_dir=tmp_path / "w")
    full_maps = upload_model(store, EXPERT.parent / "dmtl-3a")  # reads 10x10 maps only
    crowd = bundle(store, **{"model.json": json.dumps(  # 16 agents do not fit a 4 x 4 grid
        card | {"env": card["env"] | {"agents": 16}}).encode()})
    tiny = {"rows": 4, "cols": 4, "agents": 2}
    for cid, bound, why, task in (
        (no_observation, h.max_expert_bytes, "model.json: ", TINY_SPEC["env"]),
        (upload_model(store, EXPERT), 1000, "more than the bound of 1000", TINY_SPEC["env"]),
        (full_maps, h.max_expert_bytes, "cannot serve the task: DMTL", TINY_SPEC["env"]),
        (crowd, h.max_expert_bytes, "16 agents and a target do not fit on 4x4", tiny),
    ):
        h.max_expert_bytes = bound
        task_id, offered, _ = post_task(p, store, actors.requester, spec={
            **TINY_SPEC, "env": task, "experts": [cid]})
        assert offered == [h.address]
        out = h.handle(task_id, offered[0])
        assert out["status"] == "declined" and f"expert {cid}" in out["reason"], out
        assert why in out["reason"]
        assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED
        assert not (h.job_dir(task_id) / "experts").exists()


def test_the_experts_nets_count_against_the_workers_memory(env, store, tmp_path) -> None:
    """A worker sizes a task with its experts before accepting: memory for the spec alone is
    not enough when the experts' weights, observers and forward pass do not fit beside it."""
    from workers.mdrl.resources import estimate

    p, actors = env
    cid = upload_model(store, EXPERT)
    spec = {**TINY_SPEC, "experts": [cid], "algorithm": {"demonstration": {"rate": 0.5}}}
    parsed = TrainingSpec.from_dict(spec)
    alone = estimate(parsed).memory_bytes
    h = OfferHandler(account=p.chain._keys[p.chain.accounts[2]], platform=p, store=store,
                     data_dir=tmp_path / "w", memory_bytes=alone, max_jobs=1)  # the spec fits
    task_id, offered, _ = post_task(p, store, actors.requester, spec=spec)
    assert offered == [h.address]
    out = h.handle(task_id, offered[0])
    assert out["status"] == "declined", out
    assert out["reason"].startswith("spec_exceeds_worker_memory") and "1 expert(s)" in out["reason"]
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED
    assert not (h.job_dir(task_id) / "experts").exists()  # nothing fetched


def test_an_offer_naming_a_path_as_expert_is_declined(env, store, tmp_path) -> None:
    p, actors = env
    spec = {**TINY_SPEC, "experts": ["runs/my-model"]}  # the core's form, not the platform's
    task_id, offered, _ = post_task(p, store, actors.requester, spec=spec)
    h = OfferHandler(
        account=p.chain._keys[offered[0]], platform=p, store=store, data_dir=tmp_path / "w"
    )
    out = h.handle(task_id, offered[0])
    assert out["status"] == "declined" and "expert runs/my-model: not a model CID" in out["reason"]
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED


def train_offer(p, actors, store, spec: dict, tmp_path: Path, points: list | None = None):
    """Post ``spec``, let its first offeree's handler train and submit it; (handler, task id,
    the outcome's card as the store holds it); ``points`` collects the progress points."""
    task_id, offered, _ = post_task(p, store, actors.requester, spec=spec)
    h = OfferHandler(
        account=p.chain._keys[offered[0]], platform=p, store=store, data_dir=tmp_path / "w"
    )
    sink = [] if points is None else points
    h._post_progress = lambda tid, point: sink.append(point)  # type: ignore[method-assign]
    out = h.handle(task_id, offered[0])
    assert out["status"] == "submitted", out
    card_cid, _ = read_bundle(store, out["cid"])["model.json"]
    return h, task_id, json.loads(store.get(card_cid))


def test_an_medc_offer_trains_with_its_expert_and_the_card_lists_it(env, store, tmp_path) -> None:
    p, actors = env
    cid = upload_model(store, EXPERT)
    spec = {**TINY_SPEC, "experts": [{"model": cid, "qos": 0.25}],
            "algorithm": {"demonstration": {"rate": 0.5}}}
    points: list = []
    h, task_id, card = train_offer(p, actors, store, spec, tmp_path, points)
    listed = card["training"]["experts"]["experts"]
    assert [(e["ref"], e["qos"]) for e in listed] == [(cid, 0.25)]
    # the live curve carries the share of expert-guided episodes per update (R_E = 0.5)
    shares = [pt["guided_share"] for pt in points if "guided_share" in pt]
    assert shares and all(0.0 <= x <= 1.0 for x in shares) and 0.2 < sum(shares) / len(shares)
    assert sum(shares) / len(shares) < 0.8
    assert h._state(task_id)["experts"] == [cid]  # fetched, and removed once submitted
    assert not (h.job_dir(task_id) / "experts").exists()


def test_an_expert_of_qos_zero_is_neither_fetched_nor_listed(env, store, tmp_path) -> None:
    """R_S = QoS / sum QoS never picks an expert of QoS 0: the worker does not download it
    (here it is in no store at all: fetching it would fail the job) and the card does not
    list it among the experts used."""
    p, actors = env
    cid = upload_model(store, EXPERT)
    elsewhere = EmbeddedStore(tmp_path / "elsewhere")
    card = json.loads((EXPERT / "model.json").read_text())
    ghost = add_bundle(elsewhere, {
        "model.safetensors": (EXPERT / "model.safetensors").read_bytes(),
        "model.json": json.dumps({**card, "name": "never fetched"}).encode(),
    })
    spec = {**TINY_SPEC, "experts": [{"model": ghost, "qos": 0}, {"model": cid, "qos": 0.5}],
            "algorithm": {"demonstration": {"rate": 0.5}}}
    h, task_id, card = train_offer(p, actors, store, spec, tmp_path)
    listed = card["training"]["experts"]["experts"]
    assert [(e["ref"], e["qos"]) for e in listed] == [(cid, 0.5)]
    assert h._state(task_id)["experts"] == [cid]


def walls_cae(tmp_path: Path, grid: tuple[int, int] = (6, 6), d: int = 16) -> Path:
    """An (untrained) walls CAE for the 6 x 6 tiny task, written as the product writes one."""
    from workers.mdrl.cae import WallsCAE, save_cae
    from workers.mdrl.spec import EnvSpec

    torch.manual_seed(0)
    return save_cae(
        tmp_path / "cae",
        WallsCAE(grid, embedding=d),
        EnvSpec(rows=grid[0], cols=grid[1], walls=(1, 2)),
    )


def cae_spec(cid: str, d: int = 16) -> dict:
    return {
        **TINY_SPEC,
        "env": {**TINY_SPEC["env"], "walls": [1, 2]},
        "observation": {
            **TINY_SPEC["observation"],
            "walls_embedding": cid,
            "walls_embedding_size": d,
        },
    }


def test_a_task_naming_a_walls_cae_trains_with_it_and_the_card_names_its_cid(
    env, store, tmp_path
) -> None:
    """observation.walls_embedding (Ch. 4 CAE) by CID: the worker fetches and verifies it,
    trains with its encoder, and the outcome's card names the CAE by CID, not by a path on
    the worker; the card's encoder digest is the CAE's."""
    from workers.mdrl.cae import load_cae_card

    p, actors = env
    local = walls_cae(tmp_path)
    cid = upload_model(store, local)
    h, task_id, card = train_offer(p, actors, store, cae_spec(cid), tmp_path)
    assert card["observation"]["walls_embedding"] == cid
    assert card["walls_encoder"]["source"] == cid
    assert card["walls_encoder"]["digest"] == load_cae_card(local)["encoder_digest"]
    assert not (h.job_dir(task_id) / "cae").exists()  # removed once submitted (_prune)


def test_a_walls_cae_that_is_not_one_or_misses_the_grid_is_declined_naming_its_cid(
    env, store, tmp_path
) -> None:
    """Checked before accepting (the card alone tells): a policy where the CAE belongs, a CAE
    for another grid and a CID the store does not hold are declined, not accepted and then
    failed on chain."""
    p, actors = env
    policy = upload_model(store, EXPERT)  # a policy's bundle where a CAE belongs
    with pytest.raises(ExpertFetchError) as err:
        fetch_walls_cae(store, policy, tmp_path / "job")
    reason = err.value.reason
    assert "not a walls CAE card" in reason
    assert not list((tmp_path / "job" / "cae").glob("*/model.json"))  # nothing kept
    wrong_grid = upload_model(store, walls_cae(tmp_path / "big", grid=(8, 8)))
    missing = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
    for n, (ref, named) in enumerate(
        [(policy, "walls CAE"), (wrong_grid, "8x8"), (missing, missing)]
    ):
        task_id, offered, _ = post_task(p, store, actors.requester, spec=cae_spec(ref))
        h = OfferHandler(
            account=p.chain._keys[offered[0]], platform=p, store=store,
            data_dir=tmp_path / f"w{n}",
        )
        out = h.handle(task_id, offered[0])
        assert out["status"] == "declined" and f"expert {ref}" in out["reason"], out
        assert named in out["reason"], out
        assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED


def test_the_expert_credit_rule_and_rate_schedule_of_a_spec_reach_the_selector(
    store, tmp_path: Path
) -> None:
    cid = upload_model(store, EXPERT)
    doc = {**TINY_SPEC, "experts": [cid], "algorithm": {"demonstration": {"credit": True}}}
    dirs = fetch_experts(store, [cid], tmp_path / "job")
    assert jobs.make_selector(TrainingSpec.from_dict(doc), dirs).credit
    plain = {**TINY_SPEC, "experts": [cid]}
    assert not jobs.make_selector(TrainingSpec.from_dict(plain), dirs).credit
    assert jobs.make_selector(TrainingSpec.from_dict(plain), dirs).config.rate_end is None
    scheduled = {**plain, "algorithm": {"demonstration": {"rate": 0.3, "rate_end": 0.0}}}
    selector = jobs.make_selector(TrainingSpec.from_dict(scheduled), dirs)
    assert (selector.rate, selector.config.rate_end) == (0.3, 0.0)


# -- the requester's CLI ----------------------------------------------------------------------


def test_task_submit_expert_options_are_checked_before_anything_is_sent(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from drlaas.cli import app

    cid = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
    key = tmp_path / "r.key"
    base = ["task", "submit", "--key", str(key), "--gateway", "http://127.0.0.1:9"]
    cases = {
        ("--experts", "oracle"): "model CIDs",
        ("--experts", cid, "--experts-from-mmc", "2"): "give one of",
        ("--expert-qos", "1"): "--expert-qos weighs --experts",
        ("--experts", cid, "--expert-qos", "1,2"): "2 weight(s) for 1 expert(s)",
        ("--expert-rate", "0.5"): "need experts",
        ("--expert-credit",): "need experts",
        ("--experts", cid, "--expert-rate", "1.5"): "algorithm.demonstration.rate",
        ("--expert-rate-end", "0"): "need experts",
        ("--experts", cid, "--expert-rate-end", "2"): "algorithm.demonstration.rate_end",
        ("--expert-allocation", "3", "--expert-price-wei", "5"): "prices --experts-from-mmc",
        ("--keep-best", "fastest"): "selection.keep_best",
    }
    for args, msg in cases.items():
        res = CliRunner().invoke(app, [*base, *args])
        text = " ".join(res.output.replace("│", " ").split())
        assert res.exit_code == 2 and msg in text, (args, res.output)
    assert not key.exists()  # refused before a key was even created

    from drlaas.commands.client.tasks import task_body

    body = task_body(
        grid="6x6",
        agents=2,
        walls="0",
        kind="odmtl",
        window=3,
        steps=1000,
        minutes=5,
        seed=1,
        workers=1,
        payment_wei=1,
        deadline_s=600,
        domain=0,
        spec=None,
        experts=cid,
        expert_qos="0.4",
        expert_threshold=0.1,
        expert_credit=True,
        keep_best="time",
    )
    assert body["selection"] == {"keep_best": "time"}
    assert body["experts"] == [{"model": cid, "qos": 0.4}]
    assert body["algorithm"] == {"demonstration": {"threshold": 0.1, "credit": True}}
    fields = ("env", "budget", "experts", "algorithm", "selection")
    assert TrainingSpec.from_dict({k: body[k] for k in fields}).selection.keep_best == "time"


def test_model_push_adds_a_cae_or_a_model_to_the_platform_store(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`drlaas model push DIR`: the directory is checked (a CAE or a policy that loads), added
    to the platform's store (here the embedded one of DRLAAS_DATA_DIR) and its CID printed,
    which the worker then fetches and verifies as a walls CAE."""
    from typer.testing import CliRunner

    from drlaas.cli import app

    monkeypatch.setenv("DRLAAS_DATA_DIR", str(tmp_path / "platform"))
    monkeypatch.setenv("DRLAAS_IPFS", "embedded")
    cae = walls_cae(tmp_path)
    res = CliRunner().invoke(app, ["model", "push", str(cae), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert out["kind"] == "walls CAE"
    platform_store = EmbeddedStore(tmp_path / "platform" / "ipfs")
    assert fetch_walls_cae(platform_store, out["cid"], tmp_path / "job").is_dir()
    res = CliRunner().invoke(app, ["model", "push", str(EXPERT), "--json"])
    assert res.exit_code == 0 and json.loads(res.stdout)["kind"] == "model", res.output
    # a policy pushed with no key could be listed by whoever reads the store first: said
    assert "readable in the store before any commitment" in res.stderr
    assert "before any commitment" not in CliRunner().invoke(app, ["model", "push", str(cae)]
                                                             ).stderr  # a CAE is not listed
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "model.json").write_text('{"format": "drlaas-model/1", "kind": "cae"}')
    res = CliRunner().invoke(app, ["model", "push", str(bad)])
    assert res.exit_code == 1 and "not a model or walls CAE directory" in res.output


def test_an_expert_that_cannot_serve_the_task_is_named(store, tmp_path: Path) -> None:
    dmtl = Path(__file__).resolve().parents[2] / "models" / "dmtl-2a"  # full 10x10 maps
    cid = upload_model(store, dmtl)
    spec = medc_spec(cid)
    dirs = fetch_experts(store, spec.experts, tmp_path / "job")
    with pytest.raises(ExpertFetchError, match=f"expert {cid}: cannot guide this task: .*10x10"):
        jobs.make_selector(spec, dirs)


def test_an_offer_that_expires_during_the_checks_is_not_accepted(
    env, store, tmp_path, monkeypatch
) -> None:
    """Fetching and loading the experts takes time: when the acceptance window closed
    meanwhile, the worker does not send an acceptOffer the chain would revert; it records
    the offer as expired and holds no job."""
    p, actors = env
    cid = upload_model(store, EXPERT)
    task_id, offered, _ = post_task(p, store, actors.requester, spec={**TINY_SPEC,
                                                                       "experts": [cid]})
    h = OfferHandler(account=p.chain._keys[offered[0]], platform=p, store=store,
                     data_dir=tmp_path / "w")
    slow = jobs.check_job_models

    def slow_check(*args, **kw):  # noqa: ANN002, ANN003 - the job's own check, then time passes
        slow(*args, **kw)
        p.chain.advance_time(3600)

    monkeypatch.setattr(jobs, "check_job_models", slow_check)
    out = h.handle(task_id, offered[0])
    assert out["status"] == "offer expired", out
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.OFFERED  # never accepted
    assert h._state(task_id)["phase"] == "closed" and h.active_jobs(exclude=-1) == []
    assert not (h.job_dir(task_id) / "experts").exists()  # pruned with the job
