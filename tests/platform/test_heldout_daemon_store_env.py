"""Held-out pass on the worker daemon's environment: every ``DRLAAS_WORKER_*`` variable (and
``DRLAAS_GATEWAY``) is checked before the chain, the store or a key is touched, and a bad one
is named with its value."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from drlaas.cli import app
from workers.daemon import links, tasks

BAD_VALUES = [
    ("DRLAAS_WORKER_MAX_JOBS", "two"),
    ("DRLAAS_WORKER_MAX_JOBS", "0"),
    ("DRLAAS_WORKER_MAX_JOBS", "-1"),
    ("DRLAAS_WORKER_MAX_JOBS", "1.5"),
    ("DRLAAS_WORKER_MAX_JOBS", "9" * 5000),  # past int()'s digit limit
    ("DRLAAS_WORKER_CHECKPOINT_EVERY", "0"),
    ("DRLAAS_WORKER_CHECKPOINT_EVERY", "1_0"),
    ("DRLAAS_WORKER_CHECKPOINT_INTERVAL_S", "nan"),
    ("DRLAAS_WORKER_CHECKPOINT_INTERVAL_S", "inf"),
    ("DRLAAS_WORKER_CHECKPOINT_INTERVAL_S", "-5"),
    ("DRLAAS_WORKER_CHECKPOINT_INTERVAL_S", "soon"),
    ("DRLAAS_WORKER_MODEL_CACHE_BYTES", "2GiB"),
    ("DRLAAS_WORKER_OFFER_FETCH_BYTES", "-1"),
    ("DRLAAS_GATEWAY", "127.0.0.1:8000"),
    ("DRLAAS_GATEWAY", "ftp://gateway"),
]


@pytest.fixture
def nothing_opened(monkeypatch: pytest.MonkeyPatch) -> None:
    """The chain, the pins and the store must not be asked: the check comes first."""

    def asked(*args: object, **kw: object) -> None:
        raise AssertionError("the chain or the store was opened before the variables were checked")

    for name in ("pinned_platform", "connect_worker", "open_store", "record_pin"):
        monkeypatch.setattr(links, name, asked)


@pytest.mark.parametrize(("name", "value"), BAD_VALUES)
def test_a_bad_worker_variable_is_named_before_anything_is_opened(
    name: str, value: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, nothing_opened: None
) -> None:
    """``int()`` of a bad DRLAAS_WORKER_MAX_JOBS raised "invalid literal" after the chain and
    the pin file were set up, naming no variable; NaN or 0 were taken as given."""
    monkeypatch.setenv("DRLAAS_WORKER_KEY", str(tmp_path / "worker.key"))
    monkeypatch.delenv("DRLAAS_GATEWAY", raising=False)
    monkeypatch.setenv(name, value)
    with pytest.raises(tasks.WorkerEnvError, match=name) as caught:
        tasks.runtime_from_env()
    assert repr(value) in str(caught.value)
    assert isinstance(caught.value, ValueError)


def test_a_data_variable_naming_a_file_is_refused(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, nothing_opened: None
) -> None:
    (tmp_path / "data").write_text("a file, not a directory")
    monkeypatch.setenv("DRLAAS_WORKER_KEY", str(tmp_path / "worker.key"))
    monkeypatch.setenv("DRLAAS_WORKER_DATA", str(tmp_path / "data"))
    with pytest.raises(tasks.WorkerEnvError, match="DRLAAS_WORKER_DATA must be a directory"):
        tasks.runtime_from_env()


def test_a_missing_key_file_names_the_variable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, nothing_opened: None
) -> None:
    monkeypatch.setenv("DRLAAS_WORKER_KEY", str(tmp_path / "absent.key"))
    with pytest.raises(tasks.WorkerEnvError, match="DRLAAS_WORKER_KEY=.*key file not found"):
        tasks.runtime_from_env()


def test_unset_variables_give_the_defaults() -> None:
    env = tasks.worker_env({"DRLAAS_WORKER_KEY": "w.key", "DRLAAS_WORKER_MAX_JOBS": " 3 "})
    assert (env.max_jobs, env.checkpoint_every, env.checkpoint_interval_s) == (3, 2, 30.0)
    assert env.gateway_url is None and env.data_dir is None


def test_worker_run_refuses_a_bad_variable_before_making_its_key(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``drlaas worker run`` with a bad DRLAAS_WORKER_MODEL_CACHE_BYTES made the key, asked the
    faucet and took the daemon's lock first; now it ends with one line naming the variable."""
    for var in ("DRLAAS_CHAIN", "DRLAAS_GATEWAY", "DRLAAS_WORKER_DATA"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("DRLAAS_DATA_DIR", str(tmp_path / "data"))
    key = tmp_path / "worker.key"
    result = CliRunner().invoke(
        app, ["worker", "run", "--key", str(key)],
        env={"DRLAAS_WORKER_MODEL_CACHE_BYTES": "lots"},
    )
    assert result.exit_code == 1, result.output
    assert "DRLAAS_WORKER_MODEL_CACHE_BYTES" in result.output and "'lots'" in result.output
    assert "Traceback" not in result.output
    assert not key.exists()
