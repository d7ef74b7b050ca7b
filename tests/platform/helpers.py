"""Shared set-up of the platform tests: a deployed platform, registered actors, a task spec."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from backend.chain.client import Chain
from backend.chain.platform import Platform, deploy_platform, gpu_mask
from backend.store import ContentStore

DOMAIN = 0
#: CPU-only workers (GPU series 0) must be accepted, as on this machine.
ALL_GPUS = gpu_mask(range(256))
REWARD = 10**15
#: A tiny training budget: five updates of 464 env steps on a 6x6 grid, 2 agents.
TINY_SPEC: dict[str, Any] = {
    "env": {"rows": 6, "cols": 6, "agents": 2},
    "observation": {"kind": "odmtl", "window": 3},
    "budget": {"steps": 1900},
    "seed": 3,
}


def deploy(chain: Chain) -> Platform:
    return deploy_platform(
        chain, accept_window=600, review_window=3600, accepted_gpus=ALL_GPUS, worker_approval=False
    )


@dataclass
class Actors:
    requester: str
    workers: list[str]


def register(p: Platform, requester: str, workers: list[str], cores: int = 2) -> Actors:
    p.umc.add_requester(requester)
    for w in workers:
        p.umc.add_worker(w, [DOMAIN], cores, 4, 0)
    return Actors(requester, workers)


def post_task(
    p: Platform,
    store: ContentStore,
    requester: str,
    spec: dict[str, Any] | None = None,
    num_workers: int = 1,
    duration: int = 3600,
) -> tuple[int, list[str], str]:
    """Store the spec, addTask with its CID, allocateTask; returns (task id, offered, cid)."""
    cid = store.add(json.dumps(spec or TINY_SPEC).encode())
    task_id, _ = p.tmc.add_task(
        requester,
        domain=DOMAIN,
        num_workers=num_workers,
        reward=REWARD,
        duration=duration,
        description=cid,
    )
    offered, _ = p.tmc.allocate(requester, task_id)
    return task_id, offered, cid


def post_scenario_task(p: Any, *, steps: int, minutes: float) -> tuple[Any, int, Any, Any]:
    """On a ``running_platform`` with one worker: demo user1 registers as a requester and
    posts a one-worker task of the scenario env; (user1's session, task id, the worker
    offered it, its job directory)."""
    from drlaas.commands.scenario import SCENARIO_ENV, DemoUser

    req = DemoUser(p.url, "user1")
    req.post("/users/requesters", auth=True)
    created = req.post(
        "/tasks",
        {
            "env": SCENARIO_ENV,
            "observation": {"kind": "odmtl", "window": 3},
            "budget": {"steps": steps, "minutes": minutes},
            "seed": 1,
            "num_workers": 1,
            "payment_wei": 10**16,
        },
        auth=True,
    )
    task_id, worker = created["task_id"], p.workers[0]
    assert created["offered"] == [worker.address]
    job = p.data_dir / "workers" / worker.address / "jobs" / p.chain.platform.identity
    return req, task_id, worker, job / str(task_id)
