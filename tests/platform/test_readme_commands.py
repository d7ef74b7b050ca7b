"""README.md's "Join as a worker / post a task" commands, run literally from a fresh directory.

The platform line (``drlaas up ...``) is started in-process (``running_platform`` with no
workers) and its address given as ``DRLAAS_GATEWAY`` (the commands name no gateway: the
default, 127.0.0.1:8000, may be taken on this machine); ``HOME`` is a fresh directory, and no
other ``DRLAAS_*`` variable is set. Every other line runs as written: the worker in the
background, the requester's commands one after the other.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
import typer
from typer.testing import CliRunner

from backend.store import NotFound
from backend.store.bundle import pull_model, read_bundle
from backend.store.dag import compute_cid
from drlaas.cli import app
from drlaas.commands.up import REPO, running_platform
from workers.daemon.keys import load_key

SECTION = "## Join as a worker / post a task"
pytestmark = pytest.mark.slow


def readme_commands() -> list[str]:
    """The command lines of the first ``bash`` block after :data:`SECTION`."""
    text = (REPO / "README.md").read_text()
    assert SECTION in text, f"README.md has no {SECTION!r} section"
    block = re.search(r"```bash\n(.*?)```", text[text.index(SECTION) :], re.S)
    assert block is not None, "the section has no ```bash block"
    lines = [ln.strip() for ln in block.group(1).splitlines()]
    return [ln for ln in lines if ln and not ln.startswith("#")]


def test_readme_block_is_what_this_test_runs() -> None:
    cmds = readme_commands()
    assert cmds[0].startswith("drlaas up ") and "--workers 0" in cmds[0]
    assert sum(c.startswith("drlaas worker run ") for c in cmds) == 1
    assert [c.split()[1:3] for c in cmds if c.startswith("drlaas task ")] == [
        ["task", "submit"],
        ["task", "wait"],
        ["task", "pull"],
    ]


def fresh_env(home: Path, gateway: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("DRLAAS_")}
    env.update(
        HOME=str(home),
        DRLAAS_GATEWAY=gateway,
        PATH=os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")]),
        PYTHONPATH=str(REPO),
        OMP_NUM_THREADS="1",
    )
    return env


def run(cmd: str, cwd: Path, env: dict[str, str], timeout: float = 600) -> str:
    done = subprocess.run(
        shlex.split(cmd), cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    assert done.returncode == 0, f"{cmd}\n--- stdout\n{done.stdout}\n--- stderr\n{done.stderr}"
    return done.stdout


def test_readme_worker_and_requester_commands(data_dir: Path, tmp_path: Path) -> None:
    cmds = readme_commands()
    worker_cmd = next(c for c in cmds if c.startswith("drlaas worker run "))
    requester_cmds = [c for c in cmds[1:] if c != worker_cmd]
    cwd, home = tmp_path / "fresh", tmp_path / "home"
    cwd.mkdir()
    home.mkdir()
    with running_platform(workers=0, data_dir=data_dir) as p:
        env = fresh_env(home, p.url)
        log = (tmp_path / "worker.log").open("w")
        worker = subprocess.Popen(
            shlex.split(worker_cmd),
            cwd=cwd,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            api = httpx.Client(base_url=p.url + "/api", timeout=30)
            key = cwd / shlex.split(worker_cmd)[shlex.split(worker_cmd).index("--key") + 1]
            address = wait_registered(api, key, worker, tmp_path / "worker.log")
            assert p.chain.call(p.chain.platform.umc, "workerId", address) != 0  # on chain
            outputs = {}
            for cmd in requester_cmds:
                outputs[cmd] = run(cmd, cwd, env)
                if " task submit " in f" {cmd} ":
                    task = api.get("/tasks/1").json()
                    # allocated on chain to the README's worker (the relayed addTask + allocate)
                    assert [o["worker"] for o in task["offers"]] == [address], task
            task = api.get("/tasks/1").json()
            outcome = task["outcomes"][0]
            assert outcome["worker"] == address
            assert task["progress"], "the worker posted no training progress"
            assert max(pt["step"] for pt in task["progress"]) <= 2000 * 2  # the tiny budget
            # the outcome is sealed to the requester: the chain's CID gives anyone the card,
            # not the weights; the requester's download (opened with its key) is the outcome
            # on chain, file by file
            store = p.app.state.store
            with pytest.raises(NotFound):
                pull_model(store, outcome["cid"], tmp_path / "anyone")
            out_dir = cwd / shlex.split(requester_cmds[-1])[-1]
            files = read_bundle(store, outcome["cid"])
            for name in ("model.safetensors", "model.json"):
                assert compute_cid((out_dir / name).read_bytes()) == files[name][0]
            assert json.loads((out_dir / "model.json").read_text())["env"]["agents"] == 2
            # an outcome is listed only once its requester accepted it (the chain's rule,
            # asked before the store is read), and a listed model must be fetchable: sharing
            # it unpublished is refused, the worker's `worker share` publishes the files
            card_env = json.dumps(json.loads((out_dir / "model.json").read_text())["env"])
            share = ["drlaas", "model", "share", "--cid", outcome["cid"], "--key", key.name,
                     "--env", card_env]
            early = subprocess.run(share, cwd=cwd, env=env, capture_output=True, text=True,
                                   timeout=300)
            assert early.returncode != 0 and "models_outcome_not_accepted" in early.stderr, early
            run(f"drlaas task review 1 --worker {address} --review 5 --key me.key", cwd, env)
            sealed = subprocess.run(share, cwd=cwd, env=env, capture_output=True, text=True,
                                    timeout=300)
            assert sealed.returncode != 0 and "model_weights_sealed" in sealed.stderr, sealed
            run(f"drlaas worker share 1 --key {key.name}", cwd, env)
            published = pull_model(store, outcome["cid"], tmp_path / "published")
            assert (published / "model.safetensors").read_bytes() == (
                out_dir / "model.safetensors"
            ).read_bytes()
            listed = api.get("/models").json()["data"]
            assert [x["cid"] for x in listed] == [outcome["cid"]], listed
            # the worker's own files are in the per-user default, nothing in the fresh dir
            assert (home / ".drlaas" / "workers" / address).is_dir()
            assert not (cwd / ".drlaas").exists()
        except BaseException:
            print((tmp_path / "worker.log").read_text()[-4000:])
            raise
        finally:
            if worker.poll() is None:
                os.killpg(worker.pid, signal.SIGTERM)
            try:
                worker.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(worker.pid, signal.SIGKILL)
                worker.wait(timeout=10)
            log.close()


def wait_registered(
    api: httpx.Client, key: Path, worker: subprocess.Popen[bytes], log: Path
) -> str:
    """The worker's address, once its record is on chain (and indexed)."""
    deadline = time.monotonic() + 180
    while True:
        if worker.poll() is not None:
            raise AssertionError(f"worker exited ({worker.returncode}):\n{log.read_text()[-4000:]}")
        if time.monotonic() > deadline:
            raise AssertionError(f"worker did not register:\n{log.read_text()[-4000:]}")
        if key.is_file():
            address = load_key(key).address
            r = api.get(f"/workers/{address}")
            if r.status_code == 200 and r.json().get("address") == address:
                return address
        time.sleep(0.5)


def test_every_documented_command_exists() -> None:
    """Each ``drlaas <command> [<subcommand>]`` named in README.md or docs/ is a real command
    (a group must be followed by one of its subcommands) whose ``--help`` works."""
    root = typer.main.get_command(app)
    assert hasattr(root, "commands")  # a group (typer's own click)
    named: set[tuple[str, ...]] = set()
    for doc in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        for m in re.finditer(r"drlaas ([a-z][\w-]*)(?: ([a-z][\w-]*))?", doc.read_text()):
            named.add(tuple(w for w in m.groups() if w))
    assert ("worker", "run") in named and ("task", "pull") in named
    runner = CliRunner()
    for words in sorted(named):
        cmd = root.get_command(None, words[0])  # type: ignore[arg-type]
        assert cmd is not None, f"`drlaas {words[0]}` is documented but does not exist"
        path = words[:1]
        if hasattr(cmd, "commands"):
            assert len(words) == 2 and cmd.get_command(None, words[1]) is not None, (  # type: ignore[arg-type]
                f"`drlaas {' '.join(words)}`: {words[0]} needs one of {sorted(cmd.commands)}"
            )
            path = words
        done = runner.invoke(app, [*path, "--help"])
        assert done.exit_code == 0, f"drlaas {' '.join(path)} --help: {done.output}"
