"""The client CLI as a new user meets it (user audit): a pull never overwrites a folder's
files, a mistyped --key makes no key, `worker share` looks where `worker run` keeps its data,
`task cancel` says what it did or why it cannot, and tables print CIDs whole. No platform: a
fake gateway (test_hostile_gateway_client) or none at all."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Any

import pytest
from eth_account import Account
from typer.testing import CliRunner, Result

from backend.chain.platform import TaskStatus
from backend.store import EmbeddedStore
from backend.store.bundle import upload_model
from drlaas.cli import app
from drlaas.commands.client import models as model_commands
from drlaas.commands.client.session import table
from drlaas.commands.client.txcheck import TMC, pin_file
from workers.daemon.keys import load_or_create_key

from .test_cli_errors import dead_url
from .test_hostile_gateway_client import (
    ADDRS,
    EXPERT,
    Fake,
    call_data,
    fake,  # noqa: F401 - the fake gateway fixture
    review_tx,
)


def run(*args: str, input: str | None = None) -> Result:
    return CliRunner().invoke(app, list(args), input=input, env={"COLUMNS": "200"})


def said(res: Result) -> str:
    """What the command printed, on one line (a usage error's box undone)."""
    return " ".join(res.output.replace("│", " ").split())


# -- model pull into a folder that holds files ---------------------------------------------------
@pytest.fixture
def stored_model(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> str:
    """EXPERT's bundle CID in a local store that ``model pull`` reads as the gateway's."""
    store = EmbeddedStore(tmp_path / "ipfs")
    cid = upload_model(store, EXPERT)
    monkeypatch.setattr(model_commands, "GatewayBlocks",
                        lambda gateway: contextlib.nullcontext(store))
    return cid


def test_a_pull_leaves_a_folder_with_files_alone_unless_forced(
    stored_model: str, tmp_path: Path
) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "model.json").write_text("{}")
    pull = ("model", "pull", stored_model, "--out", str(out), "--gateway", dead_url())
    res = run(*pull)
    assert res.exit_code == 1, res.output
    assert f"--out {out} is not empty" in said(res) and "--force" in said(res), res.output
    assert sorted(p.name for p in out.iterdir()) == ["model.json", "notes.txt"]
    assert (out / "model.json").read_text() == "{}"

    res = run(*pull, "--force")  # replaced by the model: the user's files go
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == ["model.json", "model.safetensors"]
    assert (out / "model.json").read_bytes() == (EXPERT / "model.json").read_bytes()
    assert [p.name for p in tmp_path.iterdir() if "pulling" in p.name] == []

    res = run(*pull)  # the same model again: nothing to do
    assert res.exit_code == 0 and "already holds it" in res.output, res.output

    (out / "model.json").write_text("{}")  # that model's files, one of them changed
    res = run(*pull)
    assert res.exit_code == 1 and "is not empty" in said(res), res.output


def test_a_pull_into_a_new_or_empty_folder_needs_no_force(
    stored_model: str, tmp_path: Path
) -> None:
    (tmp_path / "empty").mkdir()
    for out in (tmp_path / "empty", tmp_path / "new" / "model"):
        res = run("model", "pull", stored_model, "--out", str(out), "--gateway", dead_url())
        assert res.exit_code == 0, res.output
        assert sorted(p.name for p in out.iterdir()) == ["model.json", "model.safetensors"]
    (tmp_path / "file").write_text("x")
    res = run("model", "pull", stored_model, "--out", str(tmp_path / "file"), "--force",
              "--gateway", dead_url())
    assert res.exit_code == 1 and "is a file, not a folder" in said(res), res.output


# -- a mistyped --key ------------------------------------------------------------------------------
ADDRESS = "0x" + "12" * 20
NEEDS_AN_EXISTING_KEY = [
    ("worker", "status"),
    ("worker", "share", "1"),
    ("task", "pull", "1"),
    ("task", "review", "1", "--worker", ADDRESS, "--review", "3"),
    ("task", "allocate", "1"),
    ("task", "cancel", "1", "--yes"),
    ("model", "review", "1", "--model", "1", "--review", "3"),
    ("pin", "show"),
    ("pin", "forget"),
]


@pytest.mark.parametrize("args", NEEDS_AN_EXISTING_KEY, ids=" ".join)
def test_a_key_path_with_no_key_fails_naming_it_where_no_key_could_act(
    args: tuple[str, ...], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Commands that only read, or act on what a key already has (its task, allocation,
    outcome), made a new key file at a mistyped --key (and pinned the platform beside it)."""
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("DRLAAS_KEY", raising=False)
    key = tmp_path / "typo.key"
    gateway = () if args == ("pin", "show") else ("--gateway", dead_url())
    res = run(*args, "--key", str(key), *gateway)
    assert res.exit_code != 0, res.output
    assert str(key) in said(res) and "Traceback" not in res.output, res.output
    assert not key.exists() and not pin_file(key).exists()


def test_a_key_is_still_made_by_the_commands_that_can_be_its_first_use(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))
    key = tmp_path / "new.key"
    res = run("requester", "register", "--key", str(key), "--gateway", dead_url())
    assert res.exit_code == 1 and "cannot reach" in res.output, res.output  # no platform...
    assert key.is_file()  # ...but the key is made, as documented


# -- worker share: where worker run keeps its data -------------------------------------------------
def test_worker_share_looks_where_worker_run_keeps_its_jobs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """It opened (and pinned the platform in) a worker directory without jobs and then said
    only that the worker submitted no outcome: it names the folder and --data."""
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv("DRLAAS_DATA_DIR", raising=False)
    key = tmp_path / "worker.key"
    address = load_or_create_key(key).address
    share = ("worker", "share", "1", "--key", str(key), "--gateway", dead_url())
    res = run(*share)
    where = tmp_path / "home" / ".drlaas" / "workers" / address
    assert res.exit_code == 1 and f"no worker's jobs in {where}" in said(res), res.output
    assert "--data DIR" in said(res) and "DRLAAS_DATA_DIR" in said(res)
    assert not where.exists()
    monkeypatch.setenv("DRLAAS_DATA_DIR", str(tmp_path / "data"))  # as `worker run` reads it
    res = run(*share)
    assert f"no worker's jobs in {tmp_path / 'data' / 'workers' / address}" in said(res)
    res = run(*share, "--data", str(tmp_path / "mine"))
    assert f"no worker's jobs in {tmp_path / 'mine'}: give the folder" in said(res), res.output


# -- task cancel -----------------------------------------------------------------------------------
def open_task(requester: str, **change: Any) -> dict[str, Any]:
    return {"id": 1, "requester": requester, "status": "open", "num_workers": 2,
            "reward_wei": str(10**15), "reward_eth": "0.001", "env": None,
            "description": "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy", **change}


def cancel_answers(gateway: Fake, me: str, task: dict[str, Any], tx_data: str) -> None:
    """The gateway's: task 1 is ``task``; its cancel asks for ``tx_data`` to be signed; the
    relayed transaction credits ``me`` the escrow of both slots."""
    tx = review_tx(me, to=ADDRS[TMC], data=tx_data)
    gateway.routes["/api/tasks/1"] = lambda f, b: (200, task)
    gateway.routes["/api/tasks/1/cancel"] = lambda f, b: (
        409, {"detail": {"rule": "sign_locally", "msg": "sign it", "tx": tx}})
    events = [{"contract": TMC, "name": "PaymentCredited",
               "args": {"account": me, "taskId": 1, "amount": 2 * 10**15}},
              {"contract": TMC, "name": "TaskStatusUpdated", "args": {"taskId": 1, "status": 3}}]
    gateway.routes["/api/tx"] = lambda f, b: (200, {"tx_hash": "0x" + "ab" * 32,
                                                 "block_number": 1, "status": 1,
                                                 "events": events})


def cancel_data(task_id: int = 1, status: TaskStatus = TaskStatus.CANCELLED) -> str:
    return call_data(TMC, "updateTaskStatus", task_id, int(status))


def test_task_cancel_signs_the_cancel_and_says_what_was_refunded(
    fake: Fake, tmp_path: Path  # noqa: F811
) -> None:
    key = tmp_path / "me.key"
    me = load_or_create_key(key).address
    cancel_answers(fake, me, open_task(me), cancel_data())
    cancel = ("task", "cancel", "1", "--key", str(key), "--gateway", fake.url)
    res = run(*cancel, input="n\n")  # asked first: no
    assert res.exit_code == 1 and "Cancel task 1" in res.output, res.output
    assert fake.posted("/api/tasks/1/cancel") == []
    res = run(*cancel, input="y\n")
    assert res.exit_code == 0, res.output
    assert "task 1 cancelled" in res.output and "0.002 ETH refunded" in res.output, res.output
    (relayed,) = fake.posted("/api/tx")
    assert Account.recover_transaction(relayed["raw"]) == me
    res = run(*cancel, "--yes", "--json")
    assert res.exit_code == 0 and json.loads(res.stdout)["refunded_wei"] == 2 * 10**15


@pytest.mark.parametrize("tx_data", [cancel_data(2), cancel_data(status=TaskStatus.CLOSED)],
                         ids=["another task", "closed, not cancelled"])
def test_task_cancel_signs_nothing_but_the_cancel_of_that_task(
    fake: Fake, tmp_path: Path, tx_data: str  # noqa: F811
) -> None:
    key = tmp_path / "me.key"
    me = load_or_create_key(key).address
    cancel_answers(fake, me, open_task(me), tx_data)
    res = run("task", "cancel", "1", "--yes", "--key", str(key), "--gateway", fake.url)
    assert res.exit_code == 1 and "tx_refused by this client" in res.output, res.output
    assert fake.posted("/api/tx") == []


def test_task_cancel_says_why_a_task_cannot_be_cancelled(
    fake: Fake, tmp_path: Path  # noqa: F811
) -> None:
    key = tmp_path / "me.key"
    me = load_or_create_key(key).address
    cancel = ("task", "cancel", "1", "--yes", "--key", str(key), "--gateway", fake.url)
    fake.routes["/api/tasks/1"] = lambda f, b: (
        404, {"detail": {"rule": "task_not_found", "msg": "no task 1 (or not indexed yet)"}})
    assert "no task 1 on" in said(run(*cancel))
    cancel_answers(fake, me, open_task(ADDRESS), cancel_data())
    res = run(*cancel)
    assert res.exit_code == 1 and f"task 1 is not yours: its requester is {ADDRESS}" in said(res)
    cancel_answers(fake, me, open_task(me, status="completed"), cancel_data())
    assert "task 1 is completed: only an open task can be cancelled" in said(run(*cancel))
    cancel_answers(fake, me, open_task(me), cancel_data())
    fake.routes["/api/tasks/1/cancel"] = lambda f, b: (
        409, {"detail": {"rule": "tasks_has_live_offers", "msg": "TasksHasLiveOffers(1)"}})
    res = run(*cancel)
    assert res.exit_code == 1 and "may still accept it" in said(res), res.output
    assert fake.posted("/api/tx") == []


# -- tables ----------------------------------------------------------------------------------------
def test_tables_print_cids_whole_and_cut_long_text() -> None:
    """`model list` printed `bafybeigdyrzt5sfp7ud…` cut in the middle: users copy CIDs."""
    cid = "bafybeigdyrzt5sfp7udm7hu76uh7y26nf3efuylqabf3oclgtqy55fbzdi"
    text = "a description much longer than any column of a table should be"
    out = table([{"cid": cid, "env": f"spec {cid}", "text": text}],
                [("cid", "CID"), ("env", "ENVIRONMENT"), ("text", "DESCRIPTION")])
    row = out.splitlines()[2]
    assert row.count(cid) == 2, row
    assert text not in row and "…" in row
