"""Held-out inputs to the platform commands of the CLI (second pass): a nested model card to
`model push`, a `--spec` file that is missing, not JSON, nested, no object or endless, and a
folder holding a large file under a model file's name. No platform: the gateway is a dead
URL or a local store. Each test fails on the code before its fix (see its docstring)."""

from __future__ import annotations

import contextlib
import json
import shutil
import tracemalloc
from pathlib import Path

import pytest
from typer.testing import CliRunner, Result

from backend.store import EmbeddedStore
from backend.store.bundle import upload_model
from drlaas.cli import app
from drlaas.commands.client import models as model_commands
from workers.mdrl.trainingspec import MAX_SPEC_BYTES

from .test_cli_errors import dead_url

EXPERT = Path(__file__).resolve().parents[2] / "models" / "odmtl-2a"


def run(*args: str) -> Result:
    return CliRunner().invoke(app, list(args), env={"COLUMNS": "200"})


def said(res: Result) -> str:
    """What the command printed, on one line (a usage error's box undone)."""
    return " ".join(res.output.replace("│", " ").split())


def test_model_push_of_a_card_nested_past_the_parser_is_one_line(tmp_path: Path) -> None:
    """`model push` read model.json itself (whole, through symlinks) to tell a walls CAE
    from a policy, and a card of 100,000 ``[`` ended it with a RecursionError traceback."""
    d = tmp_path / "model"
    d.mkdir()
    (d / "model.json").write_text("[" * 100_000)
    shutil.copy(EXPERT / "model.safetensors", d / "model.safetensors")
    res = run("model", "push", str(d), "--gateway", dead_url())
    assert res.exit_code == 1, res.output
    assert not isinstance(res.exception, RecursionError)
    assert f"{d}: no readable model.json" in said(res), res.output


@pytest.mark.parametrize(
    ("content", "why"),
    [
        (None, "No such file"),
        ("not json", "Expecting value"),
        ("[" * 50_000, "recursion"),
        ("[1, 2]", "is a JSON object, not list"),
        (json.dumps({"seed": 0, "pad": "x" * MAX_SPEC_BYTES}), f"more than {MAX_SPEC_BYTES}"),
    ],
    ids=["missing", "not-json", "nested", "a-list", "too-big"],
)
def test_a_spec_file_that_is_no_task_body_is_a_usage_error_naming_it(
    tmp_path: Path, content: str | None, why: str
) -> None:
    """`task submit --spec FILE` did ``json.loads(FILE.read_text())`` alone: a missing,
    non-JSON or nested file ended it with a traceback, a list went on to sign in and fail
    later, and a file of any size was read whole and posted. Now each is a usage error
    (exit 2) naming --spec and the file, before the gateway is reached."""
    spec = tmp_path / "spec.json"
    if content is not None:
        spec.write_text(content)
    res = run("task", "submit", "--key", str(tmp_path / "me.key"), "--spec", str(spec),
              "--gateway", dead_url())
    assert res.exit_code == 2, res.output
    assert "--spec" in said(res) and str(spec) in said(res) and why in said(res), res.output
    assert not (tmp_path / "me.key").exists()  # nothing done


def test_a_folder_holding_a_large_file_under_a_model_files_name_is_not_read_whole(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`model pull` into a folder holding the model's file names hashed each file, read
    whole into memory, to see whether it already holds the model: a 64 MiB file (any size:
    a user's own) took 64 MiB. A file of another size than the manifest's is not read."""
    store = EmbeddedStore(tmp_path / "ipfs")
    cid = upload_model(store, EXPERT)
    monkeypatch.setattr(model_commands, "GatewayBlocks",
                        lambda gateway: contextlib.nullcontext(store))
    out = tmp_path / "mine"
    out.mkdir()
    shutil.copy(EXPERT / "model.json", out / "model.json")
    with open(out / "model.safetensors", "wb") as fh:  # sparse: no disk used
        fh.truncate(64 * 2**20)
    tracemalloc.start()
    try:
        res = run("model", "pull", cid, "--out", str(out), "--gateway", dead_url())
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert res.exit_code == 1 and f"--out {out} is not empty" in said(res), res.output
    assert peak < 16 * 2**20, peak
