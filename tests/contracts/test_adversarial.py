"""Every role tries every other role's actions: each attempt must revert with the right
custom error and leave the platform state (balances, credits, tasks, offers, counters,
models) exactly as it was."""

from __future__ import annotations

from typing import Any

import pytest

from backend.chain import errors
from backend.chain.client import Chain
from backend.chain.platform import Platform, TaskStatus

from .conftest import DOMAIN, actors_of, anvil_binary, make_platform
from .helpers import CID, cid_for

REWARD = 10**16


@pytest.fixture(scope="module")
def world(request: pytest.FixtureRequest) -> dict[str, Any]:
    """A platform mid-flow: task 1 with W1 accepted+submitted and W2 offered (NW = 2), W3
    registered but not offered, a model of W1 allocated to R (allocation 1). On anvil when
    installed (hundreds of view calls), else on the embedded chain."""
    if anvil_binary() is not None:
        chain = Chain.rpc(request.getfixturevalue("anvil_url"), n_dev_accounts=24)
        snap = chain.snapshot()
        request.addfinalizer(lambda: chain.revert(snap))
    else:
        chain = Chain.embedded(accounts=12)
    p = make_platform(chain)
    a = actors_of(chain)
    r, r2 = a.requester, a.other_requester
    w1, w2, w3 = a.workers[:3]
    for req in (r, r2):
        p.umc.add_requester(req)
    p.umc.add_worker(w1, [DOMAIN], 32, 64, 1)
    p.umc.add_worker(w2, [DOMAIN], 16, 64, 1)
    p.umc.add_worker(w3, [DOMAIN], 1, 64, 1)
    tid, _ = p.tmc.add_task(r, domain=DOMAIN, num_workers=2, reward=REWARD, duration=86_400)
    offered, _ = p.tmc.allocate(r, tid)
    assert offered == [w1, w2]
    p.tmc.transact("acceptOffer", tid, sender=w1)
    p.tmc.submit_outcome(w1, tid, CID)
    mid, _ = p.mmc.add_model(w1, cid_for("own"), DOMAIN, [1, 2])  # an own upload, no outcome
    alloc, ids, _ = p.mmc.allocate(r, domain=DOMAIN, num_models=1, env=[1, 2], price=REWARD)
    assert ids == [mid]
    roles = {
        "admin": a.admin,
        "requester": r,
        "other_requester": r2,
        "worker": w1,
        "offered_worker": w2,
        "other_worker": w3,
        "outsider": a.outsider,
    }
    world = {"chain": chain, "p": p, "roles": roles, "task": tid, "alloc": alloc, "model": mid}
    world["digest"] = digest(chain, p, roles, tid, mid)
    return world


def digest(chain: Chain, p: Platform, roles: dict[str, str], tid: int, mid: int) -> tuple:
    """Everything an attempt could change, read through the public views."""
    accts = list(roles.values())
    return (
        tuple(chain.balance(x) for x in accts + [c.address for c in p.contracts]),
        tuple(p.tmc.call("credits", x) for x in accts),
        tuple(p.mmc.call("credits", x) for x in accts),
        tuple(p.tmc.call("getTask", tid)),
        tuple(tuple(p.tmc.call("getOffer", tid, x)) for x in accts),
        tuple(tuple(p.umc.call("counters", x, DOMAIN, t)) for x in accts for t in (0, 1)),
        tuple(p.umc.call("getWorker", x) for x in accts),
        tuple(p.umc.call("isAdmin", x) for x in accts),
        tuple(p.umc.call("isPlatform", x) for x in accts),
        p.mmc.call("getModel", mid),
        tuple(p.mmc.call("ownerRep", x) for x in accts),
        (p.tmc.call("w1"), p.tmc.call("acceptWindow"), p.tmc.call("acceptedGpus")),
        p.tmc.call("minRewardPerHour"),
        (p.tmc.call("taskCount"), p.mmc.call("modelCount"), p.mmc.call("allocCount")),
    )


# (role, contract, function, args builder, expected error). Args builders get the world.
T = lambda w: w["task"]  # noqa: E731
CASES: list[tuple[str, str, str, Any, str]] = []
for role in ("requester", "worker", "outsider"):
    CASES += [
        (role, "umc", "setAdmin", lambda w: (w["roles"]["outsider"], True), "UsersNotAdmin"),
        (role, "umc", "setPlatform", lambda w: (w["roles"]["outsider"], True), "UsersNotAdmin"),
        (role, "tmc", "setConfig", lambda w: (1, 1, 1), "TasksNotAdmin"),
        (role, "tmc", "setGpuSeries", lambda w: (0, True), "TasksNotAdmin"),
        (role, "tmc", "setMinRewardPerHour", lambda w: (10**18,), "TasksNotAdmin"),
    ]
for role in ("admin", "requester", "worker", "outsider"):
    CASES.append(
        (
            role,
            "umc",
            "updateInfo",
            lambda w: (w["roles"]["worker"], DOMAIN, 0, 4, 0),
            "UsersNotPlatform",
        )
    )
for role in ("requester", "outsider"):
    CASES += [
        (role, "umc", "updateStatus", lambda w: (2,), "UsersNotWorker"),
        (role, "umc", "updateCapabilities", lambda w: (1, 1, 1), "UsersNotWorker"),
        (role, "mmc", "addModel", lambda w: (CID, "", DOMAIN, [1]), "ModelsNotWorker"),
    ]
for role in ("admin", "worker", "outsider"):
    CASES += [
        (
            role,
            "tmc",
            "addTask",
            lambda w: ((DOMAIN, 1, 0, 0, 0, 0, 100, ""),),
            "TasksNotRequester",
        ),
        (
            role,
            "mmc",
            "allocateModel",
            lambda w: ((DOMAIN, 1, 0, 0, 0, 0, [1, 2], []),),
            "ModelsNotRequester",
        ),
    ]
for role in ("other_requester", "worker", "offered_worker", "outsider"):
    CASES += [
        (role, "tmc", "allocateTask", lambda w: (T(w),), "TasksNotTaskRequester"),
        (
            role,
            "tmc",
            "reviewOutcome",
            lambda w: (T(w), w["roles"]["worker"], 5, True),
            "TasksNotTaskRequester",
        ),
        (
            role,
            "tmc",
            "updateTaskStatus",
            lambda w: (T(w), int(TaskStatus.CANCELLED)),
            "TasksNotTaskRequester",
        ),
    ]
for role in ("admin", "other_requester", "worker", "offered_worker", "outsider"):
    CASES.append(
        (
            role,
            "mmc",
            "updateModelRep",
            lambda w: (w["alloc"], w["model"], 5),
            "ModelsNotAllocationRequester",
        )
    )
for role in ("admin", "requester", "worker", "other_worker", "outsider"):
    CASES += [
        (role, "tmc", "acceptOffer", lambda w: (T(w),), "TasksNotOfferedWorker"),
        (role, "tmc", "declineOffer", lambda w: (T(w),), "TasksNotOfferedWorker"),
    ]
for role in ("admin", "requester", "offered_worker", "other_worker", "outsider"):
    CASES.append((role, "tmc", "submitOutcome", lambda w: (T(w), CID), "TasksNotAssignedWorker"))
for role in ("other_requester", "other_worker", "outsider"):
    CASES.append(
        (
            role,
            "tmc",
            "updateTaskStatus",
            lambda w: (T(w), int(TaskStatus.CLOSED)),
            "TasksNotParticipant",
        )
    )
for role in ("other_requester", "other_worker", "outsider", "worker"):
    CASES += [
        (role, "tmc", "withdraw", lambda w: (), "TasksNothingToWithdraw"),
    ]
for role in ("other_requester", "offered_worker", "outsider"):
    CASES.append((role, "mmc", "withdraw", lambda w: (), "ModelsNothingToWithdraw"))
for role in ("offered_worker", "other_worker"):  # W1's outcome CID is W1's to share
    CASES.append(
        (role, "mmc", "addModel", lambda w: (CID, "", DOMAIN, [1]), "ModelsNotOutcomeOwner")
    )


@pytest.mark.parametrize(
    ("role", "contract", "fn", "args", "error"),
    CASES,
    ids=[f"{c[0]}-{c[1]}.{c[2]}" for c in CASES],
)
def test_role_cannot_act_for_another(world, role, contract, fn, args, error) -> None:
    chain, p, roles = world["chain"], world["p"], world["roles"]
    handle = getattr(p, contract)
    with pytest.raises(errors.get(error)) as info:
        handle.transact(fn, *args(world), sender=roles[role])
    if "account" in info.value.args_dict:
        assert info.value.args_dict["account"] == roles[role]
    assert digest(chain, p, roles, world["task"], world["model"]) == world["digest"]


def test_rightful_roles_still_can(world) -> None:
    """The same world lets each rightful role act (so the cases above fail for the role,
    not because the action is impossible)."""
    chain, p, roles = world["chain"], world["p"], world["roles"]
    snap = chain.snapshot()
    try:
        tid = world["task"]
        p.tmc.transact("acceptOffer", tid, sender=roles["offered_worker"])
        p.tmc.transact("reviewOutcome", tid, roles["worker"], 5, True, sender=roles["requester"])
        p.mmc.transact(
            "updateModelRep", world["alloc"], world["model"], 4, sender=roles["requester"]
        )
        p.mmc.transact("withdraw", sender=roles["worker"])
        p.tmc.transact("withdraw", sender=roles["worker"])
        p.tmc.transact("setGpuSeries", 0, True, sender=roles["admin"])
        p.tmc.transact("setMinRewardPerHour", 10**12, sender=roles["admin"])
        p.mmc.transact("addModel", CID, "", DOMAIN, [1], sender=roles["worker"])  # now accepted
    finally:
        chain.revert(snap)
