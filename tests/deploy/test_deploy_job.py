"""The one-shot deploy job (`drlaas deploy contracts`, as docker-compose runs it) against anvil
started from the generated genesis, and the worker key claims of `drlaas deploy worker`."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from web3 import Web3

from backend.chain.client import Chain
from backend.chain.consortium import Layout, read_key
from backend.services.chain import load_contracts
from drlaas.commands.deploy import claim_key

from .conftest import REPO, free_port, start_anvil, stop, wait_listening


def deploy_job(layout: Layout, rpc: str, *extra: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [
            sys.executable,
            "-m",
            "drlaas.cli",
            "deploy",
            "contracts",
            "--key",
            str(layout.deployer_key),
            "--rpc",
            rpc,
            "--out",
            str(layout.public / "contracts.json"),
            "--min-block",
            "0",
            *extra,
        ],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(proc: subprocess.Popen[str]) -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=300)
    return proc.returncode, out, err


def test_deploy_job_writes_contracts_json_the_gateway_loads(consortium: Layout, anvil: str) -> None:
    code, out, err = finish(deploy_job(consortium, anvil, "--cpu-workers"))
    assert code == 0, err
    assert out.startswith("deployed at block")
    path = consortium.public / "contracts.json"
    doc = load_contracts(path)
    deployer = read_key(consortium.deployer_key).address
    assert doc["admin"] == deployer
    assert doc["chain_id"] == 4242  # the genesis' chain id reached anvil and the file

    chain = Chain.rpc(anvil, private_keys=[])
    umc = chain.register("UsersManager", doc["UsersManager"])
    tmc = chain.register("TasksManager", doc["TasksManager"])
    mmc = chain.register("ModelsManager", doc["ModelsManager"])
    assert umc.call("isAdmin", deployer, sender=deployer) is True
    assert umc.call("isPlatform", tmc.address, sender=deployer) is True
    assert umc.call("isPlatform", mmc.address, sender=deployer) is True
    assert tmc.call("umc", sender=deployer) == umc.address
    assert mmc.call("umc", sender=deployer) == umc.address
    assert tmc.call("acceptedGpus", sender=deployer) & 1 == 1  # --cpu-workers: series 0 too
    assert chain.w3.eth.get_block(doc["deploy_block"])["number"] == doc["deploy_block"]

    # Run again (docker-compose up after a restart): nothing new is deployed.
    block = chain.w3.eth.block_number
    before = path.read_text()
    code, out, err = finish(deploy_job(consortium, anvil))
    assert code == 0, err
    assert out.startswith("already deployed")
    assert path.read_text() == before and chain.w3.eth.block_number == block


def test_deploy_job_waits_for_the_chain(consortium: Layout) -> None:
    port = free_port()
    job = deploy_job(consortium, f"http://127.0.0.1:{port}")  # nothing listens yet
    assert job.stderr is not None
    assert "waiting for the chain" in job.stderr.readline()  # it saw no chain, and waits
    node = start_anvil(consortium.genesis, port)
    try:
        wait_listening(node, port)
        code, out, err = finish(job)
        assert code == 0, err
        doc = json.loads((consortium.public / "contracts.json").read_text())
        w3 = Web3(Web3.HTTPProvider(f"http://127.0.0.1:{port}"))
        assert w3.eth.get_code(doc["UsersManager"])
    finally:
        if job.poll() is None:
            job.kill()
        stop(node)


def test_deploy_job_names_a_missing_key(consortium: Layout, tmp_path: Path) -> None:
    consortium.deployer_key.unlink()
    code, _, err = finish(deploy_job(consortium, "http://127.0.0.1:9"))
    assert code == 1
    assert str(consortium.deployer_key) in err


def test_each_worker_claims_its_own_key(consortium: Layout) -> None:
    first, fd1 = claim_key(consortium.worker_keys)
    second, fd2 = claim_key(consortium.worker_keys)
    try:
        assert {first.name, second.name} == {"worker-1.key", "worker-2.key"}
        with pytest.raises(RuntimeError, match="all 2 worker keys .* are in use"):
            claim_key(consortium.worker_keys)
        os.close(fd1)  # that container stopped: its key is free again
        again, fd1 = claim_key(consortium.worker_keys)
        assert again == first
    finally:
        os.close(fd1)
        os.close(fd2)


def test_deploy_worker_execs_the_daemon_with_the_claimed_key(consortium: Layout) -> None:
    # An invalid daemon option shows the exec reached `drlaas worker run` with the arguments.
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "drlaas.cli",
            "deploy",
            "worker",
            "--keys",
            str(consortium.worker_keys),
            "--max-jobs",
            "0",
        ],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert f"worker key {consortium.worker_key(1)}" in proc.stderr
    assert proc.returncode == 2 and "--max-jobs" in proc.stderr
