"""Faults of the worker daemon on the embedded stack: kill -9 mid-training and come back."""

from __future__ import annotations

import json
from pathlib import Path

from drlaas.commands.scenario import wait_for
from drlaas.commands.up import running_platform

from .conftest import worker_logs
from .helpers import post_scenario_task


def test_killed_worker_resumes_from_its_checkpoint(data_dir: Path) -> None:
    """kill -9 while training: the job is redelivered when the worker comes back and resumes
    from its last checkpoint instead of starting over; the task completes.

    The budget is training time (30 s over both runs), its steps out of reach: however fast
    the machine, the kill lands mid-training (a step budget had finished before the kill)."""
    steps = 10_000_000
    with running_platform(
        workers=1, data_dir=data_dir, worker_args=["--checkpoint-every", "1"]
    ) as p:
        p.wait_registered()
        req, task_id, worker, job = post_scenario_task(p, steps=steps, minutes=0.5)
        ckpt = job / "run" / "checkpoint" / "state.json"
        try:
            wait_for(
                "two checkpoints",
                lambda: json.loads(ckpt.read_text())["counters"] if ckpt.is_file() else {},
                lambda c: c.get("update", 0) >= 2,
                timeout=120,
                every=0.05,
            )
        except TimeoutError as exc:
            raise AssertionError(f"{exc}\n{worker_logs(p)}") from exc
        worker.proc.kill()  # SIGKILL: no warm shutdown, the message stays unacknowledged
        worker.proc.wait(timeout=10)
        killed_at = json.loads(ckpt.read_text())["counters"]["global_step"]
        assert 0 < killed_at < steps and not (job / "run" / "model").exists()

        p.start_worker(0)
        detail = wait_for(
            "the outcome after the restart",
            lambda: req.get(f"/tasks/{task_id}"),
            lambda d: bool(d["outcomes"]),
            timeout=180,
            every=0.5,
        )
        state = json.loads((job / "state.json").read_text())
        assert detail["outcomes"][0]["worker"] == worker.address
        assert detail["outcomes"][0]["cid"] == state["cid"]
        # resumed from a checkpoint at or after the one seen before the kill, not from step 0
        assert killed_at <= state["resumed_from_step"] < steps
        assert state["pid"] == p.workers[0].proc.pid
        req.close()
