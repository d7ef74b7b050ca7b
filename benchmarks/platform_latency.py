"""Latency from task submission (POST /api/tasks) to the worker's first training step, on the
embedded platform (issue 4 target: <= 2 s).

Starts ``drlaas up`` in-process with one worker daemon, submits ``--tasks`` tiny tasks one after
another and reads the time of each job's first env step from the worker's job state
(``first_step_at``, same machine clock). Prints one JSON object.

    .venv/bin/python benchmarks/platform_latency.py --tasks 5
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


from drlaas.commands.scenario import (  # noqa: E402
    SCENARIO_ENV,
    DemoUser,
)
from drlaas.commands.up import running_platform  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", type=int, default=5, help="tasks submitted one after another")
    ap.add_argument("--steps", type=int, default=1000, help="env-step budget of each task")
    args = ap.parse_args()
    data = Path(tempfile.mkdtemp(prefix="drlaas-latency-"))
    to_first, to_outcome = [], []
    with running_platform(workers=1, data_dir=data) as p:
        p.wait_registered()
        worker = p.workers[0]
        req = DemoUser(p.url, "user1")
        req.post("/users/requesters", auth=True)
        req.sign_in()
        for _ in range(args.tasks):
            t0 = time.time()
            created = req.post(
                "/tasks",
                {
                    "env": SCENARIO_ENV,
                    "observation": {"kind": "odmtl", "window": 3},
                    "budget": {"steps": args.steps, "minutes": 1},
                    "num_workers": 1,
                    "payment_wei": 10**16,
                },
                auth=True,
            )
            state_file = (
                p.data_dir
                / "workers"
                / worker.address
                / "jobs"
                / p.chain.platform.identity
                / str(created["task_id"])
                / "state.json"
            )
            deadline = time.monotonic() + 120
            while True:
                state = json.loads(state_file.read_text()) if state_file.is_file() else {}
                if state.get("phase") == "submitted":
                    break
                if time.monotonic() > deadline:
                    raise SystemExit(f"task {created['task_id']} did not finish: {state}")
                time.sleep(0.05)
            to_first.append(state["first_step_at"] - t0)
            to_outcome.append(state["submitted_at"] - t0)
        req.close()
    print(
        json.dumps(
            {
                "tasks": args.tasks,
                "steps": args.steps,
                "submit_to_first_step_s": {
                    "median": statistics.median(to_first),
                    "max": max(to_first),
                    "all": [round(x, 3) for x in to_first],
                },
                "submit_to_outcome_s": {
                    "median": statistics.median(to_outcome),
                    "max": max(to_outcome),
                },
                "target_s": 2.0,
                "met": statistics.median(to_first) <= 2.0,
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
