"""Allocation that scales (issue 8, finding 1): the gas of allocateTask and allocateModel
(both metrics) does not grow with the number of registered workers and models in the domain.
Registers N and 4N workers (one model each) through the test-only harness contracts; the
10,000-worker figures are printed by benchmarks/allocation_scale.py."""

from __future__ import annotations

from backend.chain.client import Chain
from benchmarks.allocation_scale import BLOCK_GAS, measure, seed, seeded_platform

POOL = 16
N = 40


def test_allocation_gas_does_not_grow_with_registered_candidates() -> None:
    p = seeded_platform(Chain.embedded(accounts=2), pool_size=POOL)
    seed(p, POOL // 2)
    small = measure(p)  # fewer registered than the pool holds: fewer candidates, less gas
    seed(p, N)
    at_n = measure(p)
    seed(p, 4 * N)
    at_4n = measure(p)
    assert p.umc.call("workerCount") == 4 * N and p.umc.call("queueLength", 5) == 4 * N
    assert len(p.umc.pool(5)) == POOL
    for fn in at_n:
        assert small[fn] < at_n[fn], fn  # the measurement sees the candidates it reads
        assert at_4n[fn] == at_n[fn], (fn, at_n[fn], at_4n[fn])
        assert at_4n[fn] < BLOCK_GAS // 10
