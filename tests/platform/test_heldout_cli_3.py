"""Held-out flag combinations of the CLI (third pass, 2026-12-05): `task submit`'s --grid and
--walls, options given with --spec, a --spec body whose terms are of the wrong type, and
`worker run` / `worker register` options checked only after the key, the faucet and the
daemon's lock. Each is a usage error (exit 2) naming the option, before anything is written
or asked. Each test fails on the code before its fix (see its docstring)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner, Result

from drlaas.cli import app

from .test_cli_errors import dead_url
from .test_hostile_gateway_client import Fake, fake  # noqa: F401 - the fake gateway fixture

EXPERT_CID = "bafkreihdwdcefgh4dqkjv67uzcmw7ojee6xedzdetojuzjevtenxquvyku"


def run(*args: str, env: dict[str, str] | None = None) -> Result:
    return CliRunner().invoke(app, list(args), env={"COLUMNS": "200", **(env or {})})


def said(res: Result) -> str:
    """What the command printed, on one line (a usage error's box undone)."""
    return " ".join(res.output.replace("│", " ").split())


def usage_error(res: Result, *named: str) -> None:
    assert res.exit_code == 2, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), repr(res.exception)
    assert "cannot reach" not in said(res), res.output  # refused before the gateway
    for n in named:
        assert n in said(res), res.output


@pytest.mark.parametrize(
    ("option", "value"),
    [("--grid", "10x"), ("--grid", "tenbyten"), ("--walls", "-1"), ("--walls", "a-b")],
)
def test_a_grid_or_walls_that_does_not_parse_is_a_usage_error(
    tmp_path: Path, option: str, value: str
) -> None:
    """`task submit --grid 10x` (or `--walls -1`) ended with a ValueError traceback: the
    parsers' errors were not turned into usage errors as `model request`'s were."""
    key = tmp_path / "me.key"
    res = run("task", "submit", "--key", str(key), option, value, "--gateway", dead_url())
    usage_error(res, option, repr(value))
    assert not key.exists()


@pytest.mark.parametrize(
    "extra",
    [
        ("--experts", EXPERT_CID),
        ("--workers", "3"),
        ("--payment-wei", "5"),
        ("--grid", "5x5"),
        ("--expert-credit",),
        ("--keep-best", "time"),
    ],
    ids=lambda a: a[0],
)
def test_options_that_spec_would_drop_are_refused_naming_them(
    tmp_path: Path, extra: tuple[str, ...]
) -> None:
    """`task submit --spec FILE --experts CID` submitted (and paid for) a task without the
    experts, `--workers 3` recruited the file's (or the gateway's default) workers: every
    option that builds the body was dropped silently with --spec."""
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"env": {"rows": 5, "cols": 5, "agents": 2}, "seed": 0}))
    key = tmp_path / "me.key"
    res = run("task", "submit", "--key", str(key), "--spec", str(spec), *extra,
              "--gateway", dead_url())
    usage_error(res, "--spec", extra[0], "not read with --spec")
    assert not key.exists()


@pytest.mark.parametrize(
    ("field", "value"),
    [("num_workers", "two"), ("num_workers", None), ("payment_wei", "1e18"),
     ("min_reputation", "x"), ("deadline_s", True), ("payment_wei", 1.5), ("domain", -1)],
)
def test_a_spec_body_whose_terms_are_of_the_wrong_type_is_a_usage_error(
    fake: Fake, tmp_path: Path, field: str, value: object  # noqa: F811
) -> None:
    """The CLI reads a --spec body's terms to check the addTask it signs (`int(num_workers)`):
    `"num_workers": "two"` or `null` ended `task submit` with a ValueError / TypeError
    traceback, after the key was made and signed in."""
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"env": {"rows": 5, "cols": 5, "agents": 2}, field: value}))
    key = tmp_path / "me.key"
    res = run("task", "submit", "--key", str(key), "--spec", str(spec), "--gateway", fake.url)
    usage_error(res, "--spec", str(spec), field)
    assert fake.seen == [] and not key.exists()  # nothing asked, nothing made


def test_experts_from_the_mmc_for_a_spec_without_env_is_a_usage_error(
    fake: Fake, tmp_path: Path  # noqa: F811
) -> None:
    """`--experts-from-mmc K` with a --spec lacking `env` signed in and then said only
    `error: 'env'` (a KeyError's text)."""
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"seed": 0}))
    res = run("task", "submit", "--key", str(tmp_path / "me.key"), "--spec", str(spec),
              "--experts-from-mmc", "1", "--gateway", fake.url)
    usage_error(res, "--spec", "--experts-from-mmc", "no env object")
    assert fake.seen == []


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (("--domains", "abc"), ("--domains", "'abc'")),
        (("--domains", "5-2"), ("--domains", "0-47")),
        (("--domains", "all"), ("--domains", "'all'")),
        (("--domains", "0-9"), ("--domains", "got 10")),
        (("--loglevel", "LOUD"), ("--loglevel", "'LOUD'")),
        (("--metrics-port", "70000"), ("--metrics-port",)),
    ],
)
def test_worker_run_checks_its_options_before_making_or_asking_anything(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, args: tuple[str, ...],
    named: tuple[str, ...]
) -> None:
    """`worker run --domains abc` (or 'all', which the help offered: 48 codes, the UMC takes
    4) made the key, signed in, asked the faucet and took the daemon's lock before a
    ValueError traceback; `--loglevel LOUD` failed in Celery after registering on chain."""
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("DRLAAS_DATA_DIR", raising=False)
    key = tmp_path / "w.key"
    res = run("worker", "run", "--key", str(key), *args, "--gateway", dead_url())
    usage_error(res, *named)
    assert not key.exists()


@pytest.mark.parametrize("domains", ["abc", "all"])
def test_worker_register_names_bad_domains_before_the_gateway(tmp_path: Path, domains: str) -> None:
    """`worker register --domains abc` ended with a ValueError traceback; 'all' (offered by
    the help) went to the gateway, which refused five or more domains."""
    key = tmp_path / "w.key"
    res = run("worker", "register", "--key", str(key), "--domains", domains,
              "--gateway", dead_url())
    usage_error(res, "--domains")
    assert not key.exists()
