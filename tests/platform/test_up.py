"""``drlaas up`` as a process: prints its URL, serves the API, stops everything on SIGTERM."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx

from drlaas.commands.scenario import wait_for

REPO = Path(__file__).resolve().parents[2]


def processes_mentioning(text: str) -> list[int]:
    """Pids whose command line contains ``text`` (e.g. a test's data directory)."""
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit() and int(d.name) != os.getpid():
            try:
                if text in (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(
                    errors="replace"
                ):
                    pids.append(int(d.name))
            except OSError:
                continue
    return pids


def test_up_starts_and_stops_cleanly_on_sigterm(data_dir: Path) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("DRLAAS_")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "drlaas.commands.up", "--workers", "1", "--data", str(data_dir)],
        cwd=REPO,
        env={**env, "PYTHONPATH": str(REPO)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = proc.stdout.readline()  # type: ignore[union-attr]
        assert line, f"no URL printed; stderr:\n{proc.stderr.read()[-3000:]}"  # type: ignore[union-attr]
        info = json.loads(line)
        health = httpx.get(info["url"] + "/api/health", timeout=10)
        assert health.status_code == 200
        workers = wait_for(
            "the worker in the index",
            lambda: httpx.get(info["url"] + "/api/workers", timeout=10).json()["data"],
            lambda d: len(d) == 1,
            timeout=30,
        )
        assert [w["address"] for w in workers] == info["workers"]
        assert processes_mentioning(str(data_dir))  # the worker daemon is running
    finally:
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=60)
    assert code == 0, proc.stderr.read()[-3000:]  # type: ignore[union-attr]
    time.sleep(0.5)
    assert processes_mentioning(str(data_dir)) == []  # no worker left behind
