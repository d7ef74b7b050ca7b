"""What the client CLI tells its user on an embedded platform with no worker daemon (``drlaas
up --workers 0`` in-process, shared by this module): an unknown task, a task nobody was
offered, an unregistered requester, a second review, a shared model's id and the task list's
columns (user audit). Tasks are posted in domains of their own (``DOMAIN_*``), so the tests do
not offer each other's tasks."""

from __future__ import annotations

import datetime as dt
import json
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner, Result

from backend.schemas.tasks import TaskExpertPublic
from drlaas.cli import app
from drlaas.commands.client import tasks as task_commands
from drlaas.commands.client import workers as worker_commands
from drlaas.commands.up import RunningPlatform, fund, running_platform
from workers.daemon.keys import load_or_create_key

from .conftest import SERVICE_VARS

EXPERT = Path(__file__).resolve().parents[2] / "models" / "odmtl-2a"
DOMAIN_NOBODY = 7
"""No worker is registered in it: its tasks are offered to nobody."""
DOMAIN_REVIEW = 3
"""Only the review test's worker (a demo account, signed for by the chain) is in it."""
DOMAIN_SHARE = 5
"""The share test's worker (a key file, as a daemon's) registers here."""
SMALL_TASK = ("--grid", "6x6", "--agents", "2", "--steps", "1000",
              "--payment-wei", str(10**15), "--deadline-s", "3600")
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def platform(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RunningPlatform]:
    """One embedded platform for the module (the ``data_dir`` fixture's environment, at
    module scope)."""
    root = tmp_path_factory.mktemp("cli-ux")
    with pytest.MonkeyPatch.context() as mp:
        for var in (*SERVICE_VARS, "DRLAAS_CHAIN_ID", "DRLAAS_KEY", "DRLAAS_DATA_DIR",
                    "DRLAAS_AUTH_DOMAIN", "DRLAAS_AUTH_URI"):
            mp.delenv(var, raising=False)
        mp.setenv("HOME", str(root / "home"))
        with running_platform(workers=0, data_dir=root / "data") as p:
            yield p


def cli(p: RunningPlatform, *args: str, code: int = 0) -> Result:
    res = CliRunner().invoke(app, [*args, "--gateway", p.url])
    assert res.exit_code == code, f"{args}: exit {res.exit_code}\n{res.output}"
    return res


def funded(p: RunningPlatform, key: Path) -> Path:
    """A new key holding gas money, so that it needs no faucet (which tops up 5 keys a minute
    from one client)."""
    fund(p.chain, load_or_create_key(key).address)
    return key


def requester(p: RunningPlatform, key: Path) -> Path:
    cli(p, "requester", "register", "--key", str(key))
    return key


def submitted_id(res: Result) -> int:
    found = re.search(r"task (\d+) submitted", res.stdout)
    assert found, res.output
    return int(found.group(1))


@pytest.mark.timeout(300)  # waiting for --timeout (an hour) would fail here
def test_waiting_for_an_unknown_task_fails_after_a_short_grace(
    platform: RunningPlatform, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The 404 ``task_not_found`` is taken for indexer lag only for a short while, not
    until --timeout."""
    monkeypatch.setattr(task_commands, "NOT_INDEXED_GRACE_S", 1.0, raising=False)
    res = cli(platform, "task", "wait", "99", "--timeout", "3600", code=1)
    assert "task_not_found" in res.stderr
    assert res.stderr.count("waiting up to") == 1, res.stderr


def test_a_task_offered_to_nobody_names_the_allocate_command(
    platform: RunningPlatform, tmp_path: Path
) -> None:
    key = requester(platform, tmp_path / "req.key")
    res = cli(platform, "task", "submit", "--key", str(key), "--domain", str(DOMAIN_NOBODY),
              *SMALL_TASK)
    task_id = submitted_id(res)
    assert "nobody yet" in res.stdout
    assert f"drlaas task allocate {task_id} --key {key}" in res.stderr
    # wait: said once, and it keeps waiting until --timeout
    res = cli(platform, "task", "wait", str(task_id), "--timeout", "5", code=1)
    assert res.stderr.count(f"drlaas task allocate {task_id} --key") == 1, res.stderr
    assert "no outcome after 5 s" in res.stderr


def test_submit_by_an_unregistered_requester_names_the_register_command(
    platform: RunningPlatform, tmp_path: Path
) -> None:
    key = tmp_path / "stranger.key"
    res = cli(platform, "task", "submit", "--key", str(key), "--domain", str(DOMAIN_NOBODY),
              *SMALL_TASK, code=1)
    assert "tasks_not_requester" in res.stderr  # the gateway's message is kept
    assert f"drlaas requester register --key {key}" in res.stderr


def test_a_second_review_is_refused_as_already_reviewed(
    platform: RunningPlatform, tmp_path: Path
) -> None:
    service = platform.chain
    worker = service.chain.accounts[7]  # a demo account: the chain signs for it
    with service.lock:
        service.platform.umc.add_worker(worker, [DOMAIN_REVIEW], 2, 4, 0)
    key = requester(platform, tmp_path / "req.key")
    res = cli(platform, "task", "submit", "--key", str(key), "--domain", str(DOMAIN_REVIEW),
              *SMALL_TASK)
    task_id = submitted_id(res)
    assert worker in res.stdout, "the task was not offered to the domain's one worker"
    outcome = platform.app.state.store.add(f"outcome of task {task_id}".encode())
    with service.lock:
        service.platform.tmc.transact("acceptOffer", task_id, sender=worker)
        service.platform.tmc.submit_outcome(worker, task_id, outcome)
    review = ("task", "review", str(task_id), "--worker", worker, "--review", "4",
              "--key", str(key))
    cli(platform, *review)
    blocks = service.chain.w3.eth.block_number
    res = cli(platform, *review, code=1)
    assert "outcome_already_reviewed" in res.stderr
    assert "4/5" in res.stderr  # the review given
    assert "tasks_not_submitted" not in res.stderr
    assert service.chain.w3.eth.block_number == blocks  # refused before any transaction


class SubmittedOutcome:
    """A worker's handler (``open_worker``) whose submitted outcome is the bundle ``cid``:
    what ``publish_outcome`` answers once the requester accepted it."""

    def __init__(self, cid: str, env: dict[str, Any]) -> None:
        self.cid, self.env = cid, env

    def publish_outcome(self, task_id: int) -> dict[str, Any]:
        return {"cid": self.cid, "env": self.env, "domain": DOMAIN_SHARE}


def test_worker_share_prints_the_listed_models_id(
    platform: RunningPlatform, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The relayed ``addModel``'s receipt has no ``id``: the id is its ModelAdded event's."""
    key = tmp_path / "worker.key"
    cli(platform, "worker", "register", "--key", str(key), "--domains", str(DOMAIN_SHARE))
    pushed = json.loads(cli(platform, "model", "push", str(EXPERT), "--key", str(key),
                            "--json").stdout)
    env = json.loads((EXPERT / "model.json").read_text())["env"]
    monkeypatch.setattr(worker_commands, "open_worker",
                        lambda *a: SubmittedOutcome(pushed["cid"], env))
    (tmp_path / "worker" / "jobs").mkdir(parents=True)  # the daemon's, with its outcome
    res = cli(platform, "worker", "share", "1", "--key", str(key),
              "--data", str(tmp_path / "worker"))
    listed = json.loads(cli(platform, "model", "list", "--json").stdout)["data"]
    (model,) = [m for m in listed if m["cid"] == pushed["cid"]]
    assert model["owner"] == load_or_create_key(key).address
    assert f"model {model['id']} shared" in res.stdout


def test_task_list_shows_the_deadline_in_utc_and_moves_in_words(
    platform: RunningPlatform, tmp_path: Path
) -> None:
    key = requester(platform, tmp_path / "req.key")
    task_id = submitted_id(cli(platform, "task", "submit", "--key", str(key),
                               "--domain", str(DOMAIN_NOBODY), *SMALL_TASK))
    raw = json.loads(cli(platform, "task", "list", "--json").stdout)["data"]
    (task,) = [t for t in raw if t["id"] == task_id]
    assert isinstance(task["deadline"], int) and task["env"]["moves"] == 4  # --json unchanged
    (row,) = [ln for ln in cli(platform, "task", "list").stdout.splitlines()
              if ln.split()[:1] == [str(task_id)]]
    utc = dt.datetime.fromtimestamp(task["deadline"], dt.UTC).strftime("%Y-%m-%d %H:%MZ")
    assert utc in row and str(task["deadline"]) not in row, row
    assert "4 moves" in row and " 4m " not in row, row


def test_task_cancel_refunds_an_open_task_of_yours_only(
    platform: RunningPlatform, tmp_path: Path
) -> None:
    """`drlaas task cancel` (the web page had it, the CLI did not), with the gateway's rules
    said as what is wrong: not your task, no longer open."""
    key = requester(platform, funded(platform, tmp_path / "req.key"))
    task_id = submitted_id(cli(platform, "task", "submit", "--key", str(key),
                               "--domain", str(DOMAIN_NOBODY), *SMALL_TASK))
    stranger = requester(platform, funded(platform, tmp_path / "stranger.key"))
    res = cli(platform, "task", "cancel", str(task_id), "--yes", "--key", str(stranger), code=1)
    assert f"task {task_id} is not yours" in res.stderr, res.stderr
    res = cli(platform, "task", "cancel", str(task_id), "--yes", "--key", str(key))
    assert f"task {task_id} cancelled" in res.stdout, res.output
    assert "0.001 ETH refunded to your credit" in res.stdout, res.output  # 1 worker x 10^15 wei
    res = cli(platform, "task", "cancel", str(task_id), "--yes", "--key", str(key), code=1)
    assert f"task {task_id} is cancelled: only an open task can be cancelled" in res.stderr


def test_model_share_takes_the_environment_from_the_card(
    platform: RunningPlatform, tmp_path: Path
) -> None:
    """`--env` had to be typed again (default {}: the gateway then refused the card's); it is
    the card's now, and one that differs is named with the card's. The model's CID is listed
    whole in `model list` (tables cut it in the middle)."""
    key = funded(platform, tmp_path / "owner.key")
    cli(platform, "worker", "register", "--key", str(key), "--domains", str(DOMAIN_SHARE))
    model = EXPERT.parent / "odmtl-1a"  # one agent: not the default environment's three
    cid = json.loads(cli(platform, "model", "push", str(model), "--key", str(key),
                         "--json").stdout)["cid"]
    share = ("model", "share", "--cid", cid, "--key", str(key), "--domain", str(DOMAIN_SHARE))
    res = cli(platform, *share, "--env", '{"rows": 10, "cols": 10, "agents": 3}', code=2)
    said = " ".join(res.output.replace("│", " ").split())
    assert "--env has agents=3, the card agents=1" in said, said
    res = cli(platform, *share)
    assert "shared" in res.stdout, res.output
    listed = cli(platform, "model", "list", "--q", cid).stdout
    assert cid in listed, listed



def test_task_show_gives_one_trial_and_the_middle_of_several() -> None:
    """``task show``'s SUGGESTED (TRIAL) column: a single worker's trial with its figures;
    several (one per outcome) as their middle suggestion, as the task page starts its review
    control, with each one's listed."""
    def trial(suggested: int, time: float = 12.0) -> dict:
        return {"worker": "0x" + "1" * 40, "episodes": 100, "success": 1.0, "time": time,
                "time_vs_oracle": time / 9.6, "suggested_review": suggested}

    text = task_commands.trial_text
    assert text({"trials": []}) == "" and text({}) == ""
    assert text({"trials": [trial(4)]}) == "4/5 (12.0 steps, 1.25x oracle)"
    several = TaskExpertPublic(cid="bafy", qos=None, model_id=None, reputation=None,
                               alloc_id=None, review=None,
                               trials=[trial(5), trial(1), trial(4)]).model_dump()
    assert text(several) == "4/5 (middle of 3: 1, 4, 5)"  # the gateway's suggested_review
