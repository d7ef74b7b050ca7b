"""Gas per contract function, measured on the embedded chain, against thesis Table 7.5.

Two figures per function: the receipt's ``gasUsed`` and the execution gas, i.e. ``gasUsed``
minus the intrinsic cost (21,000, calldata at 4 gas per zero byte and 16 per non-zero
byte, and for deployments 32,000 plus 2 gas per 32-byte initcode word, EIP-3860). Some
thesis figures (submitOutcome 29,374) are below what any storing transaction costs, so they
are compared with the execution gas; views (getWorkers) are measured with eth_estimateGas.
Allocation is measured over a pool of ``workers`` candidates and its growth over
``scaling`` pool sizes (thesis 7.9.5 reports 50).
"""

from __future__ import annotations

import base64
import hashlib
import random
from collections.abc import Sequence
from typing import Any

from .client import Chain, Receipt
from .platform import Metric, OfferState, Platform, TaskStatus, deploy_platform

# Thesis Table 7.5 (line 1720-1738).
THESIS_TABLE_7_5 = {
    "UMC.deployment": 735_736,
    "UMC.addWorker": 85_455,
    "UMC.addRequester": 74_569,
    "UMC.updateStatus": 37_286,
    "UMC.updateInfo": 67_486,
    "UMC.getWorkers": 95_287,
    "TMC.deployment": 1_477_451,
    "TMC.addTask": 487_452,
    "TMC.allocateTask": 1_053_842,
    "TMC.updateTaskStatus": 99_374,
    "TMC.submitOutcome": 29_374,
    "MMC.deployment": 1_357_425,
    "MMC.addModel": 634_341,
    "MMC.allocateModel": 903_842,
}

DOMAIN = 7
NUM_WORKERS = 5  # NW of the measured training task and of the model request
FIRST_WORKER = 2  # accounts 0 (admin) and 1 (requester) are not workers
CID = "bafkreidot3j5vvbthwtydmn3ny2pq2ckibhbuj5sech6wpzsxokrkqntsy"
OUTCOME_CID = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"  # not a listed one


def _model_cid(n: int) -> str:
    """The ``n``-th distinct model CID text, canonical for the contracts' CidText: a
    sha2-256 CIDv1 (raw) of some bytes in lowercase base32, the length of :data:`CID` (a suffix
    appended to a CID is no RFC 4648 encoding, which CidText refuses)."""
    digest = hashlib.sha256(f"gas-model-{n}".encode()).digest()
    return "b" + base64.b32encode(bytes.fromhex("01551220") + digest).decode().lower().rstrip("=")


def intrinsic_gas(calldata: bytes, create: bool = False) -> int:
    """21,000 + calldata cost (+ contract-creation cost) charged before any opcode runs."""
    zeros = calldata.count(0)
    gas = 21_000 + 4 * zeros + 16 * (len(calldata) - zeros)
    if create:
        gas += 32_000 + 2 * ((len(calldata) + 31) // 32)
    return gas


def _entry(name: str, rc: Receipt, create: bool = False, **extra: Any) -> dict[str, Any]:
    execution = rc.gas_used - intrinsic_gas(rc.calldata, create)
    out = {"gas_used": rc.gas_used, "execution_gas": execution}
    thesis = THESIS_TABLE_7_5.get(name)
    if thesis is not None:
        out["thesis"] = thesis
        out["ratio_gas_used"] = round(rc.gas_used / thesis, 3)
        out["ratio_execution"] = round(execution / thesis, 3)
    out.update(extra)
    return out


def _grow_pool(p: Platform, rng: random.Random, target: int, workers: list[str]) -> Receipt | None:
    """Register accounts as workers (uniform random capabilities) and give each one model,
    until the pool has ``target`` workers; returns the last addWorker receipt."""
    rc = None
    while len(workers) < target:
        acct = p.chain.accounts[FIRST_WORKER + len(workers)]
        rc = p.umc.add_worker(
            acct, [DOMAIN], rng.randint(1, 64), rng.randint(4, 256), rng.randint(1, 8)
        )
        env = [rng.randint(1, 10), rng.randint(0, 10)]
        # a CID is listed once, in lowercase base32 (the contracts' CidText)
        p.mmc.add_model(acct, _model_cid(len(workers)), DOMAIN, env, "ppo")
        workers.append(acct)
    return rc


def gas_report(workers: int = 50, scaling: Sequence[int] = (50, 200, 600), seed: int = 0) -> dict:
    """Deploy on a fresh embedded chain, run every function once and return the gas table.

    ``workers``: candidate pool for the per-function figures (thesis: 50). ``scaling``: pool
    sizes at which allocateTask and allocateModel (both metrics) are measured again.
    """
    if workers < NUM_WORKERS:
        raise ValueError(f"workers must be >= {NUM_WORKERS} (the task's NW), got {workers}")
    if any(n < NUM_WORKERS for n in scaling):
        raise ValueError(f"every scaling pool size must be >= {NUM_WORKERS}, got {scaling}")
    rng = random.Random(seed)
    chain = Chain.embedded(accounts=FIRST_WORKER + max(workers, *scaling))
    p = deploy_platform(chain, worker_approval=False)
    admin, requester = chain.accounts[0], chain.accounts[1]
    f: dict[str, dict[str, Any]] = {}
    f["UMC.deployment"] = _entry("UMC.deployment", p.receipts["UsersManager"], True)
    f["TMC.deployment"] = _entry("TMC.deployment", p.receipts["TasksManager"], True)
    f["MMC.deployment"] = _entry("MMC.deployment", p.receipts["ModelsManager"], True)

    f["UMC.addRequester"] = _entry("UMC.addRequester", p.umc.add_requester(requester))
    pool: list[str] = []
    first = chain.accounts[FIRST_WORKER]
    f["UMC.addWorker"] = _entry(
        "UMC.addWorker", p.umc.add_worker(first, [DOMAIN], 8, 32, 1), note="first worker"
    )
    _, rc = p.mmc.add_model(first, CID, DOMAIN, [3, 3], "target localization, 3 agents 3 walls")
    f["MMC.addModel"] = _entry("MMC.addModel", rc, env_attributes=2)
    pool.append(first)
    last = _grow_pool(p, rng, workers, pool)
    if last is not None:
        f["UMC.addWorker(nth)"] = _entry("UMC.addWorker(nth)", last, note="later workers")
    f["UMC.updateStatus"] = _entry(
        "UMC.updateStatus", p.umc.transact("updateStatus", 2, sender=pool[-1])
    )
    p.umc.transact("updateStatus", 1, sender=pool[-1])
    # updateInfo is platform-only: let the admin act as a platform contract to measure it.
    p.umc.transact("setPlatform", admin, True, sender=admin)
    f["UMC.updateInfo"] = _entry(
        "UMC.updateInfo",
        p.umc.transact("updateInfo", pool[0], DOMAIN, 0, 1, 0, sender=admin),
        note="first counter write of a worker/domain/type (zero -> non-zero slot)",
    )
    p.umc.transact("setPlatform", admin, False, sender=admin)
    page = min(workers, p.umc.WORKERS_PAGE)
    view_args = [DOMAIN, 0, page]
    view_gas = p.umc.estimate("getWorkers", *view_args)
    f["UMC.getWorkers"] = {
        "gas_used": view_gas,
        "execution_gas": view_gas
        - intrinsic_gas(bytes.fromhex(p.umc.contract.encode_abi("getWorkers", view_args)[2:])),
        "thesis": THESIS_TABLE_7_5["UMC.getWorkers"],
        "note": f"view, eth_estimateGas, a page of {page} of {workers} workers",
    }

    # -- training task flow ------------------------------------------------------------
    reward = 10**15
    tid, rc = p.tmc.add_task(
        requester,
        domain=DOMAIN,
        num_workers=NUM_WORKERS,
        reward=reward,
        duration=86_400,
        min_cpu_cores=2,
        description="maze cleaning, 4 agents: design env and reward, train PPO",
    )
    f["TMC.addTask"] = _entry("TMC.addTask", rc)
    offered, rc = p.tmc.allocate(requester, tid)
    f["TMC.allocateTask"] = _entry(
        "TMC.allocateTask", rc, candidates=workers, num_workers=NUM_WORKERS, offers=len(offered)
    )
    one, _ = p.tmc.add_task(requester, domain=DOMAIN, num_workers=1, reward=reward, duration=86_400)
    f["TMC.allocateTask(NW=1)"] = _entry(
        "TMC.allocateTask(NW=1)",
        p.tmc.allocate(requester, one)[1],
        candidates=workers,
        num_workers=1,
        note="scan-dominated: one offer",
    )
    f["TMC.acceptOffer"] = _entry(
        "TMC.acceptOffer", p.tmc.transact("acceptOffer", tid, sender=offered[0])
    )
    f["TMC.declineOffer"] = _entry(
        "TMC.declineOffer", p.tmc.transact("declineOffer", tid, sender=offered[1])
    )
    f["TMC.commitCid"] = _entry("TMC.commitCid", p.tmc.commit_cid(offered[0], OUTCOME_CID))
    f["TMC.submitOutcome"] = _entry(
        "TMC.submitOutcome",
        p.tmc.transact("submitOutcome", tid, OUTCOME_CID, sender=offered[0]),
        note="the reveal of commit-reveal (TMC.commitCid before, in an earlier block)",
    )
    f["TMC.reviewOutcome"] = _entry(
        "TMC.reviewOutcome",
        p.tmc.transact("reviewOutcome", tid, offered[0], 4, True, sender=requester),
    )
    assert p.tmc.offer(tid, offered[0])["state"] == OfferState.REVIEWED
    cancel_id, _ = p.tmc.add_task(
        requester, domain=DOMAIN, num_workers=2, reward=reward, duration=86_400
    )
    f["TMC.updateTaskStatus"] = _entry(
        "TMC.updateTaskStatus",
        p.tmc.transact("updateTaskStatus", cancel_id, int(TaskStatus.CANCELLED), sender=requester),
        note="cancellation with refund",
    )
    chain.advance_time(86_401)
    f["TMC.updateTaskStatus(close)"] = _entry(
        "TMC.updateTaskStatus(close)",
        p.tmc.transact("updateTaskStatus", tid, int(TaskStatus.CLOSED), sender=requester),
        note=f"close after deadline, {len(offered)} offers settled",
    )
    f["TMC.withdraw"] = _entry("TMC.withdraw", p.tmc.transact("withdraw", sender=offered[0]))

    # -- model sharing -------------------------------------------------------------------
    env = [4, 5]
    aid, ids, rc = p.mmc.allocate(
        requester,
        domain=DOMAIN,
        num_models=NUM_WORKERS,
        env=env,
        price=reward,
        metric=Metric.SHARING,
    )
    f["MMC.allocateModel"] = _entry(
        "MMC.allocateModel", rc, candidates=workers, num_models=NUM_WORKERS, metric="Eq. 22-23"
    )
    _, _, rc = p.mmc.allocate(
        requester,
        domain=DOMAIN,
        num_models=NUM_WORKERS,
        env=env,
        price=reward,
        metric=Metric.MODEL,
    )
    f["MMC.allocateModel(Eq. 12)"] = _entry(
        "MMC.allocateModel(Eq. 12)", rc, candidates=workers, num_models=NUM_WORKERS
    )
    f["MMC.allocateModel(NW=1)"] = _entry(
        "MMC.allocateModel(NW=1)",
        p.mmc.allocate(requester, domain=DOMAIN, num_models=1, env=env, price=reward)[2],
        candidates=workers,
        num_models=1,
        metric="Eq. 22-23",
        note="scan-dominated: one model",
    )
    f["MMC.updateModelRep"] = _entry(
        "MMC.updateModelRep", p.mmc.transact("updateModelRep", aid, ids[0], 5, sender=requester)
    )
    owner = p.mmc.call("getModel", ids[0])[0][0]
    f["MMC.withdraw"] = _entry("MMC.withdraw", p.mmc.transact("withdraw", sender=owner))

    # -- allocation growth ---------------------------------------------------------------
    growth: dict[str, dict[str, int]] = {
        "allocateTask": {},
        "allocateModel": {},
        "allocateModel(Eq. 12)": {},
    }
    for n in sorted(set(scaling)):
        _grow_pool(p, rng, n, pool)
        if len(pool) > n:  # pool already larger (workers > n): not measurable on this chain
            continue
        t, _ = p.tmc.add_task(
            requester, domain=DOMAIN, num_workers=NUM_WORKERS, reward=reward, duration=86_400
        )
        growth["allocateTask"][str(n)] = p.tmc.allocate(requester, t)[1].gas_used
        for key, metric in (
            ("allocateModel", Metric.SHARING),
            ("allocateModel(Eq. 12)", Metric.MODEL),
        ):
            rc = p.mmc.allocate(
                requester,
                domain=DOMAIN,
                num_models=NUM_WORKERS,
                env=env,
                price=reward,
                metric=metric,
            )[2]
            growth[key][str(n)] = rc.gas_used
    return {
        "chain": f"embedded py-evm ({chain.vm_name()})",
        "candidates": workers,
        "num_workers": NUM_WORKERS,
        "functions": f,
        "allocation_growth_gas_used": growth,
        "notes": [
            "execution_gas = gas_used - 21000 - calldata (4/16 per zero/non-zero byte)"
            " [- 32000 - 2 per initcode word for deployments]",
            "thesis figures: Table 7.5; allocateTask/allocateModel over `candidates` workers",
        ],
    }
