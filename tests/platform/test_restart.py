"""``drlaas up`` restarted after SIGTERM and after kill -9: the record is the same, nothing is
lost, no daemon outlives its platform and no job of one chain is reused on another (issue 7)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx

from drlaas.commands.scenario import (
    SCENARIO_ENV,
    DemoUser,
    run_scenario,
    wait_for,
)
from workers.daemon.gateway import Gateway

from .test_up import REPO, processes_mentioning


def start_up(data_dir: Path, workers: int = 3) -> tuple[subprocess.Popen[str], dict[str, Any]]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("DRLAAS_")}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "drlaas.commands.up",
            "--workers",
            str(workers),
            "--data",
            str(data_dir),
        ],
        cwd=REPO,
        env={**env, "PYTHONPATH": str(REPO)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    line = proc.stdout.readline()  # type: ignore[union-attr]
    if not line:
        proc.kill()
        raise AssertionError(f"drlaas up printed nothing; stderr:\n{proc.stderr.read()[-4000:]}")  # type: ignore[union-attr]
    return proc, json.loads(line)


def task_body(*, steps: int, minutes: float, seed: int) -> dict[str, Any]:
    """POST /tasks body: one worker, the scenario's small environment."""
    return {
        "env": SCENARIO_ENV,
        "observation": {"kind": "odmtl", "window": 3},
        "budget": {"steps": steps, "minutes": minutes},
        "seed": seed,
        "num_workers": 1,
        "payment_wei": 10**16,
        "deadline_s": 3600,
        "domain": 0,
    }


def rpc(url: str, method: str, *params: Any) -> Any:
    r = httpx.post(
        url + "/rpc", json={"jsonrpc": "2.0", "id": 1, "method": method, "params": list(params)}
    )
    return r.json()["result"]


def record(url: str, addresses: list[str]) -> dict[str, Any]:
    """What a user can see of the platform: tasks with offers and outcomes, models, workers with
    reputations, balances, contracts, chain height."""
    anon = httpx.Client(base_url=url + "/api", timeout=30)
    tasks = anon.get("/tasks", params={"limit": 100}).json()["data"]
    details = [anon.get(f"/tasks/{t['id']}").json() for t in tasks]
    for d in details:
        d.pop("progress", None)  # the live curve may gain points from a job still training
    out = {
        "contracts": anon.get("/chain/contracts").json(),
        "tasks": sorted(details, key=lambda d: d["id"]),
        "models": anon.get("/models").json()["data"],
        "workers": anon.get("/workers").json()["data"],
        "balances": {a: rpc(url, "eth_getBalance", a, "latest") for a in addresses},
    }
    anon.close()
    return out


def settled(rec: dict[str, Any]) -> dict[str, Any]:
    """The parts that cannot change while the platform is down (the training task may finish
    after the restart, which changes its own task row and its worker's counters)."""
    return {
        "contracts": rec["contracts"],
        "tasks": [t for t in rec["tasks"] if t["id"] != rec["training_task"]],
        "models": rec["models"],
        "balances": {a: b for a, b in rec["balances"].items() if a != rec["training_worker"]},
    }


def stop(proc: subprocess.Popen[str], sig: int) -> None:
    proc.send_signal(sig)
    proc.wait(timeout=60)


def test_restart_after_sigterm_and_kill_9_keeps_the_whole_record(data_dir: Path) -> None:
    proc, info = start_up(data_dir)
    try:
        url = info["url"]
        report = run_scenario(url, data_dir, steps=2000, say=lambda s: None)
        # one more task still training when the platform goes down
        req = DemoUser(url, "user1")
        created = req.post("/tasks", task_body(steps=40_000, minutes=10, seed=11), auth=True)
        training, worker = created["task_id"], created["offered"][0]
        wait_for(
            "training progress",
            lambda: req.get(f"/tasks/{training}"),
            lambda d: bool(d.get("progress")),
            timeout=120,
        )
        addresses = [*info["workers"], req.address, report["worker"]]
        before = record(url, addresses) | {"training_task": training, "training_worker": worker}
        height = int(rpc(url, "eth_blockNumber"), 16)
        assert before["models"] and len(before["tasks"]) == 3  # the scenario's two + this one
    finally:
        stop(proc, signal.SIGTERM)
    assert processes_mentioning(str(data_dir)) == []

    # 1. clean stop, start again: the same record, and the chain goes on from the same height
    proc, info2 = start_up(data_dir)
    try:
        assert info2["workers"] == info["workers"]
        after = record(info2["url"], addresses) | {
            "training_task": training,
            "training_worker": worker,
        }
        assert settled(after) == settled(before)
        assert int(rpc(info2["url"], "eth_blockNumber"), 16) >= height
        # the reviewed worker's reputation survived (its counters move only on chain events:
        # an offer, an acceptance, a review or a close, none of which the restart makes)
        rep = {w["address"]: w["reputation"] for w in after["workers"]}
        rep_before = {w["address"]: w["reputation"] for w in before["workers"]}
        assert rep[report["worker"]] == rep_before[report["worker"]]
    finally:
        proc.send_signal(signal.SIGKILL)  # 2. kill -9: no clean-up at all
        proc.wait(timeout=30)
    gone = wait_for(
        "the worker daemons to die with their platform",
        lambda: processes_mentioning(str(data_dir)),
        lambda pids: pids == [],
        timeout=20,
    )
    assert gone == []

    proc, info3 = start_up(data_dir)
    try:
        url3 = info3["url"]
        after = record(url3, addresses) | {"training_task": training, "training_worker": worker}
        assert settled(after) == settled(before)
        # the job that was training comes back and completes, once, for this task of this chain
        anon = Gateway(url3)
        done = wait_for(
            "the outcome of the task that was training",
            lambda: anon.get(f"/tasks/{training}"),
            lambda d: bool(d.get("outcomes")),
            timeout=300,
            every=1.0,
        )
        assert [o["worker"] for o in done["outcomes"]] == [worker]
        assert done["outcomes"][0]["cid"] != report["cid"]
        # a new task gets the next id and a fresh job: never the model of an earlier task
        req3 = DemoUser(url3, "user1")
        fresh = req3.post("/tasks", task_body(steps=2000, minutes=2, seed=7), auth=True)
        assert fresh["task_id"] == training + 1
    finally:
        stop(proc, signal.SIGTERM)
    time.sleep(0.5)
    assert processes_mentioning(str(data_dir)) == []
