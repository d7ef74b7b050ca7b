"""Differential tests: on random pools the contracts pick the same workers / models, in the
same order and with the same integer QoS, as the pure-Python reference backend/chain/qos.py
(Eq. 10-13, 16-23, greedy top-NW with ties to the earlier registration), including the
bounded candidate pool of each domain (qos decision 12: small pool sizes put some workers
behind the pool)."""

from __future__ import annotations

import dataclasses

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from backend.chain import errors, qos
from backend.chain.platform import Metric, Platform, WorkerStatus

from .conftest import ACCEPTED_GPUS, Actors, actors_of
from .helpers import cid_for

DOM = 1  # task domain; workers also cover domain 2
SETTINGS = settings(
    max_examples=12,  # CI time (each example replays transactions on py-evm); forge fuzzes more
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
    # no shrinking: every step replays transactions on py-evm (minutes); the failing
    # example is printed as generated
    phases=[Phase.explicit, Phase.reuse, Phase.generate],
    print_blob=True,
)
FLAGS = {"assigned": 1, "accepted": 2, "completed": 4}
REVIEWED = 8


@st.composite
def counters(draw: st.DrawFn) -> tuple[qos.Counters, list[int]]:
    a = draw(st.integers(0, 3))
    ac = draw(st.integers(0, a))
    e = draw(st.integers(0, ac))
    reviews = draw(st.lists(st.integers(0, qos.REVIEW_MAX), max_size=2))
    return qos.Counters(a, ac, e, sum(reviews), len(reviews)), reviews


@st.composite
def workers(draw: st.DrawFn, max_size: int = 7) -> list[tuple[qos.Worker, list[int]]]:
    n = draw(st.integers(1, max_size))
    out = []
    for _ in range(n):
        domains = draw(st.sampled_from([frozenset({DOM}), frozenset({2}), frozenset({DOM, 2})]))
        # few distinct values so that equal QoS (ties) happen often
        cores = draw(st.sampled_from([0, 2, 4, 8, 64]))
        c_tr, rev_tr = draw(counters())
        c_ms, rev_ms = draw(counters())
        w = qos.Worker(
            domains=domains,
            cpu_cores=cores,
            ram_gb=draw(st.sampled_from([4, 16, 64])),
            gpu_series=draw(st.integers(0, 4)),
            counters={(DOM, qos.TaskType.TRAINING): c_tr, (DOM, qos.TaskType.SHARING): c_ms},
            available=draw(st.booleans()),
        )
        out.append((w, [rev_tr, rev_ms]))
    return out


THRESHOLDS = st.sampled_from([0, 0, 250_000, 500_000, 700_000])
POOL_SIZES = st.sampled_from([None, None, 1, 2, 3])  # None: the contract's default (64)


def _set_pool(p: Platform, actors: Actors, workers: list[qos.Worker], size: int | None):
    """Set the UMC pool size (None: default) and return the reference pool of DOM."""
    if size is not None:
        p.umc.set_pool_size(actors.admin, size)
    return qos.domain_pool(workers, DOM, qos.POOL_SIZE if size is None else size)


def _add_models(p: Platform, addrs: list[str], workers: list[qos.Worker], specs) -> tuple:
    """List the models on chain; a model whose owner does not cover DOM is refused (the
    owner-domain rule of addModel) and left out of the reference list too."""
    ids, models = [], []
    for i, (o, e) in enumerate(specs):
        if DOM not in workers[o].domains:
            try:
                p.mmc.add_model(addrs[o], cid_for(i), DOM, e)
                raise AssertionError("a model outside the owner's domains must revert")
            except errors.get("ModelsOwnerNotInDomain"):
                continue
        ids.append(p.mmc.add_model(addrs[o], cid_for(i), DOM, e)[0])
        models.append(qos.Model(o, DOM, e))
    return ids, models


def _register(p: Platform, actors: Actors, pool: list[tuple[qos.Worker, list[int]]]) -> list[str]:
    """Register the pool on chain and replay its counters through updateInfo (admin acts as
    a platform contract for the setup only)."""
    admin = actors.admin
    p.umc.transact("setPlatform", admin, True, sender=admin)
    addrs = []
    for (w, reviews), addr in zip(pool, actors.workers, strict=False):
        p.umc.add_worker(addr, sorted(w.domains), w.cpu_cores, w.ram_gb, w.gpu_series)
        for ttype, revs in zip(qos.TaskType, reviews, strict=True):
            c = w.stats(DOM, ttype)
            for k in range(max(c.assigned, len(revs))):
                flags = sum(f for name, f in FLAGS.items() if k < getattr(c, name))
                review = 0
                if k < len(revs):
                    flags |= REVIEWED
                    review = revs[k]
                p.umc.transact("updateInfo", addr, DOM, int(ttype), flags, review, sender=admin)
        if not w.available:
            p.umc.update_status(addr, WorkerStatus.IDLE)
        addrs.append(addr)
    p.umc.transact("setPlatform", admin, False, sender=admin)
    p.umc.add_requester(actors.requester)
    return addrs


def _chain_worker(p: Platform, addr: str, w: qos.Worker) -> qos.Worker:
    """The reference worker rebuilt from on-chain counters (after offers changed them)."""
    cs = {}
    for ttype in qos.TaskType:
        c = p.umc.counters(addr, DOM, int(ttype))
        cs[(DOM, ttype)] = qos.Counters(
            c["assigned"], c["accepted"], c["completed"], c["rating_sum"], c["rating_count"]
        )
    return dataclasses.replace(w, counters=cs)


@SETTINGS
@given(
    pool=workers(),
    nw=st.integers(1, 4),
    min_rep=THRESHOLDS,
    min_rating=THRESHOLDS,
    min_cpu=st.sampled_from([0, 0, 4]),
    min_ram=st.sampled_from([0, 16]),
    size=POOL_SIZES,
)
def test_allocate_task_matches_reference(fp, pool, nw, min_rep, min_rating, min_cpu, min_ram, size):
    p = fp
    actors = actors_of(p.chain)
    snap = p.chain.snapshot()
    try:
        addrs = _register(p, actors, pool)
        ref_workers = [w for w, _ in pool]
        members = _set_pool(p, actors, ref_workers, size)
        assert set(p.umc.pool(DOM)) == {addrs[i] for i in members}
        task = qos.TrainingTask(
            DOM, nw, min_rep, min_rating, min_cpu, min_ram, frozenset(ACCEPTED_GPUS)
        )
        tid, _ = p.tmc.add_task(
            actors.requester,
            domain=DOM,
            num_workers=nw,
            reward=1,  # the least reward a task may offer
            duration=86_400,
            min_reputation=min_rep,
            min_rating=min_rating,
            min_cpu_cores=min_cpu,
            min_ram_gb=min_ram,
        )
        offered, rc = p.tmc.allocate(actors.requester, tid)
        expected = qos.recruit_training(ref_workers, task, p.tmc.call("w1"), pool=members)
        assert offered == [addrs[i] for i in expected]
        _, ref_qos = qos.training_qos_all(ref_workers, task, p.tmc.call("w1"), members)
        assert [e.args["qos"] for e in rc.named("TaskOffered")] == [ref_qos[i] for i in expected]

        if offered:  # the first offeree declines: the next best (by current counters) follows
            p.tmc.transact("declineOffer", tid, sender=offered[0])
            now = [_chain_worker(p, a, w) for a, w in zip(addrs, ref_workers, strict=True)]
            # the reference rule of the counters (docs/chain.md, "Offers that count"): offers
            # of a task still running count for nobody, declined or live, so the next best is
            # ranked on the counters registered above
            assert [w.counters for w in now] == [w.counters for w in ref_workers]
            refill = qos.recruit_training(
                now,
                dataclasses.replace(task, num_workers=1),
                p.tmc.call("w1"),
                exclude={addrs.index(a) for a in offered},
                pool=members,
            )
            again, _ = p.tmc.allocate(actors.requester, tid)
            assert again == [addrs[i] for i in refill]
    finally:
        p.chain.revert(snap)


@st.composite
def model_specs(draw: st.DrawFn, n_workers: int) -> list[tuple[int, tuple[int, ...]]]:
    d = draw(st.integers(0, 3))
    k = draw(st.integers(1, 7))
    out = []
    for _ in range(k):
        length = d if draw(st.integers(0, 5)) else (d + 1)  # some models have other dims
        env = tuple(draw(st.lists(st.integers(0, 6), min_size=length, max_size=length)))
        out.append((draw(st.integers(0, n_workers - 1)), env))
    return out


@st.composite
def sharing_case(draw: st.DrawFn):
    pool = draw(workers(max_size=5))
    specs = draw(model_specs(len(pool)))
    d = min(len(e) for _, e in specs)
    env = tuple(draw(st.lists(st.integers(0, 6), min_size=d, max_size=d)))
    weights = None
    if d and draw(st.booleans()):
        cuts = sorted(draw(st.lists(st.integers(0, qos.ONE), min_size=d - 1, max_size=d - 1)))
        bounds = [0, *cuts, qos.ONE]
        weights = tuple(b - a for a, b in zip(bounds, bounds[1:], strict=False))
    return pool, specs, env, weights


@SETTINGS
@given(
    case=sharing_case(),
    nm=st.integers(1, 4),
    min_rep=THRESHOLDS,
    min_rating=THRESHOLDS,
    size=POOL_SIZES,
)
def test_allocate_model_sharing_matches_reference(fp, case, nm, min_rep, min_rating, size):
    pool, specs, env, weights = case
    p = fp
    actors = actors_of(p.chain)
    snap = p.chain.snapshot()
    try:
        addrs = _register(p, actors, pool)
        ref_workers = [w for w, _ in pool]
        members = _set_pool(p, actors, ref_workers, size)
        ids, models = _add_models(p, addrs, ref_workers, specs)
        task = qos.SharingTask(DOM, nm, env, min_rep, min_rating, weights)
        expected = qos.recruit_sharing(models, ref_workers, task, pool=members)
        req = (DOM, nm, int(Metric.SHARING), min_rep, min_rating, 0, list(env), list(weights or ()))
        if not expected:
            try:
                p.mmc.transact("allocateModel", req, sender=actors.requester, value=nm)
                raise AssertionError("no eligible model must revert")
            except errors.get("ModelsNoEligibleModel"):
                return
        _, got, rc = p.mmc.allocate(
            actors.requester,
            domain=DOM,
            num_models=nm,
            env=env,
            min_reputation=min_rep,
            min_rating=min_rating,
            weights=weights or (),
            metric=Metric.SHARING,
        )
        assert got == [ids[i] for i in expected]
        _, ref_qos = qos.sharing_qos_all(models, ref_workers, task, members)
        assert [e.args["qos"] for e in rc.named("ModelAllocated")] == [ref_qos[i] for i in expected]
    finally:
        p.chain.revert(snap)


@SETTINGS
@given(
    case=sharing_case(),
    rounds=st.lists(
        st.tuples(st.integers(1, 3), st.lists(st.integers(0, qos.REVIEW_MAX), max_size=3)),
        max_size=3,
    ),
    nm=st.integers(1, 4),
    min_model_rep=THRESHOLDS,
    min_owner_rep=THRESHOLDS,
    size=POOL_SIZES,
)
def test_allocate_model_eq12_matches_reference(
    fp, case, rounds, nm, min_model_rep, min_owner_rep, size
):
    pool, specs, env, weights = case
    p = fp
    actors = actors_of(p.chain)
    snap = p.chain.snapshot()
    try:
        addrs = _register(p, actors, pool)
        ref_workers = [w for w, _ in pool]
        members = _set_pool(p, actors, ref_workers, size)
        ids, listed = _add_models(p, addrs, ref_workers, specs)
        specs = [(m.owner, m.env) for m in listed]
        # history: allocations (Eq. 11 counts) and some reviews (Eq. 10-11 totals)
        for k, reviews in rounds:
            try:
                alloc, got, _ = p.mmc.allocate(
                    actors.requester,
                    domain=DOM,
                    num_models=k,
                    env=env,
                    weights=weights or (),
                    metric=Metric.MODEL,
                )
            except errors.get("ModelsNoEligibleModel"):
                break  # nobody in the pool lists a model of these dimensions
            for m, r in zip(got, reviews, strict=False):
                p.mmc.transact("updateModelRep", alloc, m, r, sender=actors.requester)
        models = []
        for (o, e), mid in zip(specs, ids, strict=True):
            (owner, _, _, alloc_count, total_review), _, env_onchain = p.mmc.call("getModel", mid)
            assert owner == addrs[o] and tuple(env_onchain) == e
            models.append(qos.Model(o, DOM, e, alloc_count, total_review))
        req = qos.ModelRequest(DOM, nm, env, min_model_rep, min_owner_rep, weights)
        expected = qos.allocate_models(models, req, pool=members)
        args = dict(
            domain=DOM,
            num_models=nm,
            env=env,
            min_reputation=min_owner_rep,
            min_model_reputation=min_model_rep,
            weights=weights or (),
            metric=Metric.MODEL,
        )
        if not expected:
            try:
                p.mmc.allocate(actors.requester, **args)
                raise AssertionError("no eligible model must revert")
            except errors.get("ModelsNoEligibleModel"):
                return
        _, got, rc = p.mmc.allocate(actors.requester, **args)
        assert got == [ids[i] for i in expected]
        _, ref_qos = qos.model_qos_all(models, req, members)
        assert [e.args["qos"] for e in rc.named("ModelAllocated")] == [ref_qos[i] for i in expected]
    finally:
        p.chain.revert(snap)
