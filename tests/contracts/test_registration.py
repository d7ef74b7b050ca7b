"""Registration a stranger cannot flood (issue 8, finding 1): consortium approval, removal by
the worker or an admin, at most four domains per worker, a bounded number of models per
owner, and the bounded candidate pool of a domain (the UMC's Active queue)."""

from __future__ import annotations

import random

from backend.chain import qos
from backend.chain.platform import Metric, WorkerStatus

from .conftest import DOMAIN
from .helpers import CID, cid_for, reverts


def _task(p, requester, nw=3):
    tid, _ = p.tmc.add_task(
        requester, domain=DOMAIN, num_workers=nw, reward=10**15, duration=86_400
    )
    return tid


def test_unapproved_registrations_are_never_candidates(p, actors) -> None:
    """With approval on, a registration is Pending: no offer, no model, no pool place, until
    an admin approves it; only admins approve."""
    admin, r = actors.admin, actors.requester
    p.umc.set_approval_required(admin, True)
    p.umc.add_requester(r)
    p.umc.approve_requester(admin, r)
    good, strangers = actors.workers[0], actors.workers[1:6]
    p.umc.add_worker(good, [DOMAIN], 1, 32, 1)
    for s in strangers:  # stronger machines than the approved worker: QoS would prefer them
        rc = p.umc.add_worker(s, [DOMAIN], 64, 64, 1)
        assert rc.one("WorkerStatusUpdated").args["status"] == WorkerStatus.PENDING
        assert p.umc.status(s) == WorkerStatus.PENDING
    p.umc.approve_worker(admin, good)
    assert p.umc.pool(DOMAIN) == [good]
    offered, _ = p.tmc.allocate(r, _task(p, r))
    assert offered == [good]
    reverts("UsersNotApproved", p.umc.update_status, strangers[0], WorkerStatus.ACTIVE)
    reverts("ModelsNotApproved", p.mmc.add_model, strangers[0], CID, DOMAIN, [1])
    reverts("UsersNotAdmin", p.umc.approve_worker, strangers[1], strangers[0])
    reverts("UsersNotAdmin", p.umc.set_approval_required, strangers[1], False)
    reverts("UsersNotPending", p.umc.approve_worker, admin, good)

    rc = p.umc.approve_worker(admin, strangers[0])
    assert rc.one("WorkerApproved").args["admin"] == admin
    assert p.umc.pool(DOMAIN) == [good, strangers[0]]
    offered, _ = p.tmc.allocate(r, _task(p, r, nw=1))
    assert offered == [strangers[0]]


def test_sybil_requesters_wait_for_approval(p, actors) -> None:
    """The sybil-requester probe (docs/chain.md): an approved worker opens a second address
    as a requester to post tasks only it can take. With approval on, that address is Pending
    and cannot post a task or request models until an admin approves it; an admin (or the
    address itself) removes it for good, and a removed address cannot register again."""
    admin, r = actors.admin, actors.requester
    p.umc.set_approval_required(admin, True)
    worker, sybil = actors.workers[0], actors.workers[1]
    p.umc.add_worker(worker, [DOMAIN], 8, 32, 1)
    p.umc.approve_worker(admin, worker)
    rc = p.umc.add_requester(sybil)
    assert rc.one("RequesterStatusUpdated").args["status"] == WorkerStatus.PENDING
    assert not rc.named("RequesterAdded")
    assert p.umc.requester_status(sybil) == WorkerStatus.PENDING
    assert not p.umc.call("isRequester", sybil)
    reverts("TasksNotRequester", _task, p, sybil, 1)
    reverts("ModelsNotRequester", p.mmc.allocate, sybil, domain=DOMAIN, num_models=1, env=[1])
    reverts("UsersNotAdmin", p.umc.approve_requester, worker, sybil)
    reverts("UsersNotSelfOrAdmin", p.umc.remove_requester, worker, sybil)
    rc = p.umc.remove_requester(admin, sybil)
    assert rc.one("RequesterRemoved").args["by"] == admin
    assert p.umc.requester_status(sybil) == WorkerStatus.REMOVED
    reverts("UsersAlreadyRegistered", p.umc.add_requester, sybil)
    reverts("UsersRequesterNotPending", p.umc.approve_requester, admin, sybil)
    # an approved requester posts tasks; removed, it posts no more, its task runs on
    p.umc.add_requester(r)
    rc = p.umc.approve_requester(admin, r)
    assert rc.one("RequesterApproved").args["admin"] == admin and rc.one("RequesterAdded")
    tid = _task(p, r, 1)
    p.umc.remove_requester(r, r)
    reverts("TasksNotRequester", _task, p, r, 1)
    offered, _ = p.tmc.allocate(r, tid)
    assert offered == [worker]


def test_changed_capabilities_need_reapproval(p, actors) -> None:
    """Approval covers the capabilities a worker declared: declaring more after approval
    (65,535 cores to win every allocation) makes it Pending, out of the pool, until an admin
    approves it again; the same values again change nothing."""
    admin, r = actors.admin, actors.requester
    p.umc.set_approval_required(admin, True)
    p.umc.add_requester(r)
    p.umc.approve_requester(admin, r)
    honest, boaster = actors.workers[:2]
    for w in (honest, boaster):
        p.umc.add_worker(w, [DOMAIN], 8, 32, 1)
        p.umc.approve_worker(admin, w)
    rc = p.umc.transact("updateCapabilities", 8, 32, 1, sender=honest)  # unchanged
    assert not rc.named("WorkerStatusUpdated") and p.umc.status(honest) == WorkerStatus.ACTIVE
    rc = p.umc.transact("updateCapabilities", 65_535, 32, 1, sender=boaster)
    assert rc.one("WorkerStatusUpdated").args["status"] == WorkerStatus.PENDING
    assert p.umc.pool(DOMAIN) == [honest]
    offered, _ = p.tmc.allocate(r, _task(p, r, 1))
    assert offered == [honest]
    p.umc.approve_worker(admin, boaster)
    assert p.umc.pool(DOMAIN) == [honest, boaster]
    offered, _ = p.tmc.allocate(r, _task(p, r, 1))
    assert offered == [boaster]  # re-approved with its new capabilities, it ranks first


def test_removed_workers_are_never_offered(p, actors) -> None:
    """A worker removes itself, an admin removes another: neither is offered a task or a
    model again, neither comes back by status or by registering again."""
    admin, r = actors.admin, actors.requester
    p.umc.add_requester(r)
    ws = actors.workers[:4]
    for i, w in enumerate(ws):
        p.umc.add_worker(w, [DOMAIN], 64 - i, 64, 1)  # ws[0] is the best
        p.mmc.add_model(w, cid_for(i), DOMAIN, [1])
    reverts("UsersNotSelfOrAdmin", p.umc.remove_worker, ws[2], ws[0])
    rc = p.umc.remove_worker(ws[0], ws[0])
    assert rc.one("WorkerRemoved").args["by"] == ws[0]
    p.umc.remove_worker(admin, ws[1])
    assert p.umc.status(ws[1]) == WorkerStatus.REMOVED
    assert p.umc.pool(DOMAIN) == ws[2:]
    offered, _ = p.tmc.allocate(r, _task(p, r, nw=4))
    assert offered == ws[2:]
    _, got, _ = p.mmc.allocate(r, domain=DOMAIN, num_models=4, env=[1], metric=Metric.MODEL)
    assert [p.mmc.call("getModel", m)[0][0] for m in got] == ws[2:]  # equal QoS: lower id
    reverts("UsersNotApproved", p.umc.update_status, ws[0], WorkerStatus.ACTIVE)
    reverts("UsersNotApproved", p.umc.remove_worker, admin, ws[0])
    reverts("UsersAlreadyRegistered", p.umc.add_worker, ws[0], [DOMAIN], 1, 1, 1)
    reverts("ModelsNotApproved", p.mmc.add_model, ws[1], CID, DOMAIN, [1])


def test_a_worker_covers_at_most_four_domains(p, actors) -> None:
    w = actors.workers[0]
    err = reverts("UsersTooManyDomains", p.umc.add_worker, w, [0, 1, 2, 3, 4], 1, 1, 1)
    assert err.args_dict["maximum"] == 4
    reverts("UsersTooManyDomains", p.umc.transact, "addWorker", (1 << 48) - 1, 1, 1, 1, sender=w)
    p.umc.add_worker(w, [0, 1, 2, 47], 1, 1, 1)
    assert [p.umc.queue(d) for d in (0, 1, 2, 47, 3)] == [[w], [w], [w], [w], []]


def test_models_per_owner_are_bounded(p, actors) -> None:
    admin, w, other = actors.admin, actors.workers[0], actors.workers[1]
    p.umc.add_worker(w, [DOMAIN, DOMAIN + 1], 4, 16, 1)
    assert p.mmc.call("maxModelsPerOwner") == 8
    reverts("ModelsNotAdmin", p.mmc.set_max_models_per_owner, w, 16)
    reverts("ModelsBadLimit", p.mmc.set_max_models_per_owner, admin, 0)
    reverts("ModelsBadLimit", p.mmc.set_max_models_per_owner, admin, 17)
    p.mmc.set_max_models_per_owner(admin, 2)
    p.mmc.add_model(w, cid_for("a"), DOMAIN, [1])
    p.mmc.add_model(w, cid_for("b"), DOMAIN + 1, [1])  # the limit counts every domain
    err = reverts("ModelsOwnerLimit", p.mmc.add_model, w, cid_for("c"), DOMAIN, [1])
    assert err.args_dict["limit"] == 2
    reverts("ModelsOwnerNotInDomain", p.mmc.add_model, w, cid_for("d"), DOMAIN + 2, [1])
    reverts("ModelsNotWorker", p.mmc.add_model, other, cid_for("e"), DOMAIN, [1])


def test_pool_is_the_head_of_the_active_queue(p, actors) -> None:
    """Pool size 2: the best worker, registered third, waits behind the pool and is offered
    only once a pool member goes Idle; going Active again joins at the tail. The reference
    (qos.domain_pool with the activation order) gives the same pool."""
    admin, r = actors.admin, actors.requester
    p.umc.add_requester(r)
    reverts("UsersBadPoolSize", p.umc.set_pool_size, admin, 0)
    reverts("UsersBadPoolSize", p.umc.set_pool_size, admin, 129)
    reverts("UsersNotAdmin", p.umc.set_pool_size, r, 2)
    p.umc.set_pool_size(admin, 2)
    ws = actors.workers[:3]
    for w, cores in zip(ws, (2, 4, 64), strict=True):
        p.umc.add_worker(w, [DOMAIN], cores, 64, 1)
    assert p.umc.pool(DOMAIN) == ws[:2] and p.umc.queue(DOMAIN) == ws
    offered, _ = p.tmc.allocate(r, _task(p, r, nw=1))
    assert offered == [ws[1]]  # best of the pool, not the best registered
    p.umc.update_status(ws[0], WorkerStatus.IDLE)
    assert p.umc.pool(DOMAIN) == ws[1:]
    offered, _ = p.tmc.allocate(r, _task(p, r, nw=1))
    assert offered == [ws[2]]
    p.umc.update_status(ws[0], WorkerStatus.ACTIVE)
    assert p.umc.queue(DOMAIN) == [ws[1], ws[2], ws[0]]
    ref = [qos.Worker(frozenset({DOMAIN}), c, 64, 1) for c in (2, 4, 64)]
    assert qos.domain_pool(ref, DOMAIN, 2, order=[1, 2, 0]) == {1, 2}
    assert {ws[i] for i in qos.domain_pool(ref, DOMAIN, 2, order=[1, 2, 0])} == set(
        p.umc.pool(DOMAIN)
    )


def test_queue_links_survive_random_joins_and_leaves(p, actors) -> None:
    """The UMC's doubly linked queues against a Python list over a random walk of status
    changes and removals of workers covering two domains (head, middle and tail unlinks)."""
    rng = random.Random(8)
    ws = actors.workers[:8]
    doms = {w: [DOMAIN] if i % 3 == 0 else [DOMAIN, DOMAIN + 1] for i, w in enumerate(ws)}
    model: dict[int, list[str]] = {DOMAIN: [], DOMAIN + 1: []}
    for w in ws:
        p.umc.add_worker(w, doms[w], 4, 4, 1)
        for d in doms[w]:
            model[d].append(w)
    removed: set[str] = set()
    for _ in range(40):
        w = rng.choice([x for x in ws if x not in removed])
        active = w in model[DOMAIN] or w in model[DOMAIN + 1]
        if rng.random() < 0.08:
            p.umc.remove_worker(actors.admin, w)
            removed.add(w)
            for d in doms[w]:
                if w in model[d]:
                    model[d].remove(w)
        elif active:
            p.umc.update_status(w, WorkerStatus.IDLE)
            for d in doms[w]:
                model[d].remove(w)
        else:
            p.umc.update_status(w, WorkerStatus.ACTIVE)
            for d in doms[w]:
                model[d].append(w)
        for d in model:
            assert p.umc.queue(d) == model[d]
            assert p.umc.call("queueLength", d) == len(model[d])


def test_pending_capabilities_are_frozen_until_the_admin_decides(p, actors) -> None:
    """The audit's finding: a Pending worker declared 4 cores, swapped in 65,535 before the
    admin's approval was mined, and was approved as the pool's best. The values under review
    now cannot change (the same values can be sent again), and a removed worker's cannot;
    the worker daemon reports the frozen values instead of failing on the revert."""
    from types import SimpleNamespace

    from workers.daemon.capabilities import Capabilities
    from workers.daemon.command import register_worker

    admin = actors.admin
    p.umc.set_approval_required(admin, True)
    w = actors.workers[0]
    p.umc.add_worker(w, [DOMAIN], 4, 8, 1)
    assert p.umc.status(w) == WorkerStatus.PENDING
    reverts("UsersNotApproved", p.umc.transact, "updateCapabilities", 65_535, 8, 1, sender=w)
    p.umc.transact("updateCapabilities", 4, 8, 1, sender=w)  # unchanged: allowed
    daemon = SimpleNamespace(umc=p.umc, admin=w, chain=p.chain)
    said = register_worker(daemon, Capabilities(cpu_cores=64, ram_gb=8, gpu_series=1), (DOMAIN,))
    assert "4 cores" in said and "once approved" in said
    p.umc.approve_worker(admin, w)
    assert tuple(p.umc.call("getWorker", w))[2:5] == (1, 4, 8)  # gpu, cores, ram reviewed
    p.umc.transact("removeWorker", w, sender=w)
    reverts("UsersNotApproved", p.umc.transact, "updateCapabilities", 4, 8, 1, sender=w)
