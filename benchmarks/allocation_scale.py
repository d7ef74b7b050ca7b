"""Allocation gas against the number of registered candidates (issue 8, "allocation that scales").

Deploys the platform with the test-only harness contracts (contracts/src/mocks: the UMC and
MMC plus a bulk registration that leaves the same storage as addWorker + approveWorker and
addModel), registers N workers in one domain, each listing one model there, and measures the
gas of ``allocateTask`` (NW = 5) and ``allocateModel`` (5 models, both metrics) at every N.
Before issue 8 both scanned every registered candidate (~7.9k gas each: 30M crossed at ~3,700
workers); now they read the domain's candidate pool only (UMC ``poolSize``, default 64), so
the figures must be flat in N. A last row measures the worst case the settings allow: pool
size MAX_POOL_SIZE (128), every pool owner listing MAX_MODELS_PER_OWNER (16) models.

Usage: python benchmarks/allocation_scale.py [--sizes 1000,2000,4000,10000]
Prints one line per N and the JSON of all figures.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence

from backend.chain.client import Chain
from backend.chain.platform import (
    ALL_GPUS_BUT_NONE,
    W1_DEFAULT,
    Metric,
    ModelsManager,
    Platform,
    TasksManager,
    UsersManager,
)

DOMAIN = 5
BLOCK_GAS = 30_000_000
SEED_WORKERS_PER_TX = 150  # ~75k gas each: ~11M gas, below the 15M EIP-1559 target (base fee falls)
SEED_MODELS_PER_TX = 150
FIRST_ADDRESS = 0x10_0000  # synthetic worker addresses 0x..100000, 0x..100001, ...
NUM_WORKERS = 5
MAX_POOL_SIZE = 128  # UMC.MAX_POOL_SIZE
MAX_MODELS_PER_OWNER = 16  # MMC.MAX_MODELS_PER_OWNER
MAX_ENV_DIMS = 12  # MMC.MAX_ENV_DIMS


def seeded_platform(chain: Chain, pool_size: int | None = None) -> Platform:
    """UMC/MMC harnesses + the real TMC, wired as deploy_platform does, approval off."""
    admin = chain.accounts[0]
    umc, r_umc = chain.deploy("UsersManagerHarness", admin, sender=admin)
    tmc, r_tmc = chain.deploy(
        "TasksManager", umc.address, W1_DEFAULT, 3_600, 7 * 86_400, ALL_GPUS_BUT_NONE, sender=admin
    )
    mmc, r_mmc = chain.deploy("ModelsManagerHarness", umc.address, tmc.address, sender=admin)
    umc.transact("setPlatform", tmc.address, True, sender=admin)
    umc.transact("setPlatform", mmc.address, True, sender=admin)
    umc.transact("setApprovalRequired", False, sender=admin)
    if pool_size is not None:
        umc.transact("setPoolSize", pool_size, sender=admin)
    p = Platform(
        chain,
        admin,
        UsersManager(chain, umc.name, umc.contract),
        TasksManager(chain, tmc.name, tmc.contract),
        ModelsManager(chain, mmc.name, mmc.contract),
        {"UsersManager": r_umc, "TasksManager": r_tmc, "ModelsManager": r_mmc},
    )
    p.umc.add_requester(chain.accounts[1])
    return p


def seed(p: Platform, workers: int, models_per_owner: int = 1, dims: int = 2) -> None:
    """Register workers (and their models in DOMAIN) until the UMC holds ``workers``."""
    admin = p.admin
    have = p.umc.call("workerCount")
    while have < workers:
        n = min(SEED_WORKERS_PER_TX, workers - have)
        p.umc.transact("seedWorkers", FIRST_ADDRESS + have, n, 1 << DOMAIN, have, sender=admin)
        owners_per_tx = max(1, SEED_MODELS_PER_TX // models_per_owner)
        for start in range(have, have + n, owners_per_tx):
            k = min(owners_per_tx, have + n - start)
            p.mmc.transact(
                "seedModelsDims", start + 1, k, models_per_owner, DOMAIN, dims, sender=admin
            )
        have += n


def measure(p: Platform, env: Sequence[int] = (3, 2)) -> dict[str, int]:
    """Gas used by allocateTask and allocateModel (both metrics); state rolled back after."""
    requester = p.chain.accounts[1]
    snap = p.chain.snapshot()
    try:
        tid, _ = p.tmc.add_task(
            requester, domain=DOMAIN, num_workers=NUM_WORKERS, reward=10**12, duration=86_400
        )
        offered, rc_task = p.tmc.allocate(requester, tid)
        assert len(offered) == NUM_WORKERS
        out = {"allocateTask": rc_task.gas_used}
        for name, metric in (
            ("allocateModel", Metric.SHARING),
            ("allocateModel(Eq. 12)", Metric.MODEL),
        ):
            _, got, rc = p.mmc.allocate(
                requester,
                domain=DOMAIN,
                num_models=NUM_WORKERS,
                env=list(env),
                price=10**9,
                metric=metric,
            )
            assert len(got) == NUM_WORKERS
            out[name] = rc.gas_used
        return out
    finally:
        p.chain.revert(snap)


def scaling(sizes: Sequence[int], pool_size: int | None = None) -> dict[int, dict[str, int]]:
    """Allocation gas at each number of registered workers (one model each), one chain."""
    chain = Chain.embedded(accounts=2)
    p = seeded_platform(chain, pool_size)
    figures = {}
    for n in sorted(sizes):
        seed(p, n)
        figures[n] = measure(p)
        cells = "  ".join(f"{k} {v:>9,}" for k, v in figures[n].items())
        print(f"N={n:>6,} registered workers (one model each): {cells}", flush=True)
    return figures


def worst_case(dims: int = 2) -> dict[str, int]:
    """Largest pool (128) with every owner at the model limit (16): the settings' bound; with
    ``dims`` = MAX_ENV_DIMS (12) every model and the request have the most attributes (one
    more cold word per model)."""
    chain = Chain.embedded(accounts=2)
    p = seeded_platform(chain, pool_size=MAX_POOL_SIZE)
    seed(p, MAX_POOL_SIZE, models_per_owner=MAX_MODELS_PER_OWNER, dims=dims)
    return measure(p, env=[(3 + j) % 7 for j in range(dims)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,2000,4000,10000")
    ap.add_argument("--no-worst-case", action="store_true")
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    t0 = time.monotonic()
    figures = scaling(sizes)
    report: dict = {"pool_size": 64, "gas_used": {str(n): r for n, r in figures.items()}}
    if not args.no_worst_case:
        worst = worst_case()
        print(f"worst case (pool 128, 16 models per owner = 2,048 models): {worst}")
        report["worst_case_pool128_models16"] = worst
        worst12 = worst_case(dims=MAX_ENV_DIMS)
        print(f"worst case with {MAX_ENV_DIMS} attributes per model and request: {worst12}")
        report[f"worst_case_pool128_models16_dims{MAX_ENV_DIMS}"] = worst12
    top = max(v for r in report["gas_used"].values() for v in r.values())
    print(
        f"largest figure {top:,} gas = {top / BLOCK_GAS:.1%} of a 30M block "
        f"({time.monotonic() - t0:.0f} s)"
    )
    print(json.dumps(report))


if __name__ == "__main__":
    main()
