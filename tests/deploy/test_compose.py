"""docker-compose.yml against what `drlaas deploy init` writes: every path a service mounts is
one the generator creates, each validator gets its own key, and the commands parse. No Docker
engine runs here, so this (and `docker-compose config` when the client is installed) is what
can be checked of the file."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from backend.chain.consortium import Layout, generate
from drlaas.cli import app

from .conftest import REPO

COMPOSE = REPO / "docker-compose.yml"


@pytest.fixture(scope="module")
def compose() -> dict:
    return yaml.safe_load(COMPOSE.read_text())


def host_sources(service: dict) -> list[str]:
    return [v.split(":")[0] for v in service.get("volumes", []) if v.startswith("./")]


def test_four_validators_each_with_its_own_generated_key(compose: dict, tmp_path: Path) -> None:
    validators = {n: s for n, s in compose["services"].items() if n.startswith("validator")}
    assert sorted(validators) == ["validator1", "validator2", "validator3", "validator4"]
    keys = {n: [p for p in host_sources(s) if p.endswith(".key")] for n, s in validators.items()}
    assert all(len(k) == 1 for k in keys.values()) and len({k[0] for k in keys.values()}) == 4

    # The generator's layout, made relative to the repository as compose mounts it.
    generate(tmp_path / "deploy" / "consortium", validators=4, workers=0)
    layout = Layout(tmp_path / "deploy" / "consortium")
    for i in range(1, 5):
        key = keys[f"validator{i}"][0]
        assert (tmp_path / key).resolve() == layout.validator_key(i).resolve()
        # The enode host of validator i in static-nodes.json is its compose service name.
        assert f"@validator{i}:30303" in (layout.public / "static-nodes.json").read_text()
    for service in compose["services"].values():
        for source in host_sources(service):
            assert (tmp_path / source).exists() or source.endswith("worker-keys"), source
    for service in validators.values():
        assert "./deploy/consortium/public:/consortium:ro" in service["volumes"]
        assert "--genesis-file=/consortium/genesis.json" in service["command"]
        assert "--static-nodes-file=/consortium/static-nodes.json" in service["command"]


def test_deploy_job_gates_gateway_and_workers(compose: dict) -> None:
    services = compose["services"]
    for name in ("gateway", "worker"):
        assert services[name]["depends_on"]["deploy"] == {
            "condition": "service_completed_successfully"
        }
    assert services["deploy"]["restart"] == "no"


@pytest.mark.parametrize("service", ["deploy", "worker"])
def test_commands_parse_with_the_cli(compose: dict, service: str) -> None:
    argv = compose["services"][service]["command"]
    assert argv[:2] == ["drlaas", "deploy"]
    # --help after the subcommand parses the options given before it without running anything.
    result = CliRunner().invoke(app, [*argv[1:3], "--help"])
    assert result.exit_code == 0, result.output
    for arg in argv[3:]:
        if arg.startswith("--") and service == "deploy":
            assert arg.split("=")[0] in result.output, arg


@pytest.mark.skipif(shutil.which("docker-compose") is None, reason="docker-compose not installed")
def test_docker_compose_config_accepts_the_file() -> None:
    env = {**os.environ, "POSTGRES_PASSWORD": "x", "DRLAAS_TOKEN_SECRET": "y"}
    proc = subprocess.run(
        ["docker-compose", "-f", str(COMPOSE), "config", "--quiet"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
