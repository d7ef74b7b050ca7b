"""A platform the CLI cannot reach, settings a daemon cannot start with, a port already taken:
each ends the command with one line saying what to do, never a traceback (the user audit of
2026-12-03)."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest
from typer.testing import CliRunner

from drlaas.cli import app

from .test_hostile_gateway_client import (
    CHAIN_ID,
    Fake,
    fake,  # noqa: F401 - the fake gateway fixture
)


def run(*args: str, env: dict[str, str] | None = None) -> tuple[int, str]:
    res = CliRunner().invoke(app, list(args), env=env)
    text = res.output + (res.stderr if res.stderr_bytes is not None else "")
    return res.exit_code, text


def dead_url() -> str:
    """A loopback URL nothing listens on (a port bound, then closed)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"http://127.0.0.1:{port}"


@pytest.mark.parametrize(
    "args",
    [
        ("task", "list"),
        ("task", "show", "1"),
        ("requester", "register", "--key", "{key}"),
        ("worker", "run", "--key", "{key}"),
    ],
)
def test_a_platform_that_is_not_running_is_one_line(args, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))
    for var in ("DRLAAS_DATA_DIR", "DRLAAS_CONTRACTS", "DRLAAS_CHAIN"):
        monkeypatch.delenv(var, raising=False)
    url = dead_url()
    key = str(tmp_path / "k.key")
    code, text = run(*[a.format(key=key) for a in args], "--gateway", url)
    assert code == 1, text
    assert "Traceback" not in text and "cannot reach" in text and url in text, text
    assert "drlaas up" in text  # what to do


def test_a_worker_refused_by_its_pin_says_so_in_one_line(
    fake: Fake, tmp_path: Path, monkeypatch: pytest.MonkeyPatch  # noqa: F811
) -> None:
    """The worker's pin (platform.json) names another deployment than the gateway: one line
    naming both, in one order, and the entry to remove."""
    monkeypatch.setenv("HOME", str(tmp_path))
    for var in ("DRLAAS_CONTRACTS", "DRLAAS_CHAIN", "DRLAAS_BROKER", "DRLAAS_IPFS"):
        monkeypatch.delenv(var, raising=False)
    from workers.daemon.keys import load_or_create_key
    from workers.daemon.links import Deployment, record_pin

    key = tmp_path / "w.key"
    address = load_or_create_key(key).address
    data = tmp_path / "data"
    old = Deployment("0x" + "55" * 20, "0x" + "66" * 20, "0x" + "77" * 20)
    record_pin(data / "workers" / address / "platform.json", fake.url, old, CHAIN_ID)
    fake.routes["/api/local/services"] = lambda f, b: (200, {"data_dir": str(data)})
    code, text = run("worker", "run", "--key", str(key), "--gateway", fake.url,
                     env={"DRLAAS_DATA_DIR": str(data)})
    assert code == 1 and "Traceback" not in text, text
    line = next(x for x in text.splitlines() if x.startswith("error:"))
    assert "refusing to sign for another deployment" in line and "platform.json" in line
    names = [x.split("=")[0] for x in line.split("contracts ")[1].split(", but")[0].split(", ")]
    assert names == sorted(names) == ["ModelsManager", "TasksManager", "UsersManager"]


def test_up_on_a_port_in_use_stops_before_making_anything(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("DRLAAS_DATA_DIR", raising=False)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        data = tmp_path / "platform"
        code, text = run("up", "--workers", "0", "--port", str(port), "--data", str(data))
    assert code == 1 and "Traceback" not in text, text
    assert f"127.0.0.1:{port} is in use" in text and "--port" in text
    assert not data.exists()  # no chain, no store, no database made for nothing


def test_the_faucet_sign_in_at_start_names_the_pinned_chain(
    fake: Fake, tmp_path: Path, monkeypatch: pytest.MonkeyPatch  # noqa: F811
) -> None:
    """Before its deployment is checked the daemon signs in for the faucet: a sign-in message
    for another chain than the one pinned is not signed there either."""
    monkeypatch.setenv("HOME", str(tmp_path))
    for var in ("DRLAAS_CONTRACTS", "DRLAAS_CHAIN", "DRLAAS_BROKER", "DRLAAS_IPFS"):
        monkeypatch.delenv(var, raising=False)
    from backend.chain.pins import chain_pinned_for
    from workers.daemon.keys import load_or_create_key
    from workers.daemon.links import Deployment, record_pin

    key = tmp_path / "w.key"
    pins = tmp_path / "data" / "workers" / load_or_create_key(key).address / "platform.json"
    assert chain_pinned_for(pins, fake.url) is None
    record_pin(pins, fake.url, Deployment(*("0x" + c * 40 for c in "567")), 5)
    assert chain_pinned_for(pins, fake.url) == 5
    fake.contracts = {**fake.contracts, "rpc": "/rpc"}  # an embedded chain: an empty key
    fake.routes["/rpc"] = lambda f, b: (200, {"jsonrpc": "2.0", "id": b["id"], "result": "0x0"})
    code, text = run("worker", "run", "--key", str(key), "--gateway", fake.url,
                     env={"DRLAAS_DATA_DIR": str(tmp_path / "data")})
    assert code == 1 and "Traceback" not in text, text
    assert f"the message is for chain {CHAIN_ID}, not this platform's chain 5" in text
    assert fake.posted("/api/auth/token") == []  # nothing signed


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (("model", "request", "--grid", "abc"), "grid 'abc'"),
        (("model", "request", "--env", "notjson"), "not JSON"),
        (("model", "request", "--env", "[1, 2]"), "a JSON object"),
        (("model", "share", "--cid", "bafkreix", "--env", "notjson"), "not JSON"),
    ],
)
def test_bad_model_options_are_usage_errors_before_any_request(
    args, named, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))
    code, text = run(*args, "--key", str(tmp_path / "k.key"), "--gateway", dead_url())
    assert code == 2 and "Traceback" not in text and named in text, text
    assert "cannot reach" not in text  # refused before the gateway is asked
