"""The CLI's checks of ``sign_locally`` transactions on the normal path: against a real
embedded gateway (``drlaas up`` in-process, no workers) every write command, with keys the
gateway does not hold, signs what the gateway's routes build (the checks of
``drlaas/commands/client/txcheck.py`` pass), pins the deployment next to the key on first use,
and refuses to sign once the pinned chain or contracts are not the gateway's."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from drlaas.cli import app
from drlaas.commands.client.txcheck import (
    MMC,
    TMC,
    UMC,
    Call,
    Expect,
    expect_request,
    pin_file,
)
from drlaas.commands.up import running_platform
from workers.daemon.keys import load_or_create_key

EXPERT = Path(__file__).resolve().parents[2] / "models" / "odmtl-2a"
pytestmark = pytest.mark.slow


def test_every_write_command_signs_what_the_gateway_builds_and_pins_the_deployment(
    data_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    for var in ("DRLAAS_CHAIN_ID", "DRLAAS_KEY", "DRLAAS_TX_MAX_GAS",
                "DRLAAS_TX_MAX_FEE_PER_GAS_WEI", "DRLAAS_AUTH_DOMAIN", "DRLAAS_AUTH_URI",
                "DRLAAS_DATA_DIR"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    cli = CliRunner()
    with running_platform(workers=0, data_dir=data_dir) as p:

        def run(*args: str, env: dict[str, str] | None = None, code: int = 0) -> Any:
            res = cli.invoke(app, [*args, "--gateway", p.url, "--json"], env=env)
            assert res.exit_code == code, f"{args}: {res.output}"
            return json.loads(res.stdout) if code == 0 else res.output

        owner, req = tmp_path / "owner.key", tmp_path / "requester.key"
        # a worker (addWorker), its CID commitment (commitCid), its model (addModel: the
        # commitment is there, or a `then: repeat` first step when it is not)
        run("worker", "register", "--key", str(owner))
        pins = json.loads(pin_file(owner).read_text())
        platform = p.chain.platform
        assert pins == {
            p.url: {
                "chain_id": p.chain.chain.chain_id,
                "contracts": {
                    UMC: platform.umc.address,
                    TMC: platform.tmc.address,
                    MMC: platform.mmc.address,
                },
            }
        }
        pushed = run("model", "push", str(EXPERT), "--key", str(owner))
        env_doc = json.loads((EXPERT / "model.json").read_text())["env"]
        run("model", "share", "--key", str(owner), "--cid", pushed["cid"],
            "--env", json.dumps(env_doc))
        # a requester: register, buy the model at the MMC's minimum price x 1 (allocateModel),
        # review it, submit a task (addTask escrowing 2 x payment, then allocateTask)
        run("requester", "register", "--key", str(req))
        alloc = run("model", "request", "--key", str(req), "--grid", "6x6", "--agents", "2")
        (model,) = alloc["models"]
        run("model", "review", str(alloc["alloc_id"]), "--model", str(model["id"]),
            "--review", "4", "--key", str(req))
        assert platform.mmc.contract.functions.getModel(model["id"]).call()[0][-1] == 4
        task = run("task", "submit", "--key", str(req), "--grid", "6x6", "--agents", "2",
                   "--steps", "1000", "--workers", "2", "--payment-wei", str(10**15),
                   "--deadline-s", "3600")
        assert task["task_id"] == 1 and "allocation_error" not in task, task
        assert platform.tmc.contract.functions.getTask(1).call()[0][0] == req_address(req)
        run("task", "allocate", "1", "--key", str(req))

        # the pinned deployment is not this gateway's any more: nothing is signed
        before = p.chain.chain.w3.eth.block_number
        out = run("task", "allocate", "1", "--key", str(req), env={"DRLAAS_CHAIN_ID": "1"},
                  code=1)
        # the gateway's sign-in already names another chain: not signed, nor anything after
        cid = p.chain.chain.chain_id
        assert f"not signed: the message is for chain {cid}, not this platform's chain 1" in out
        pins = json.loads(pin_file(req).read_text())
        pins[p.url]["contracts"][TMC] = "0x" + "42" * 20
        pin_file(req).write_text(json.dumps(pins))
        out = run("task", "allocate", "1", "--key", str(req), code=1)
        assert f"to is {platform.tmc.address}, none of the platform's contracts" in out
        assert str(pin_file(req)) in out and "remove" in out
        assert p.chain.chain.w3.eth.block_number == before  # no transaction was mined


def req_address(key: Path) -> str:
    return str(load_or_create_key(key).address)


def test_each_route_expects_the_call_the_gateway_sends_for_it() -> None:
    me = "0x" + "ab" * 20
    names = {
        ("/users/requesters", None): ["UsersManager.addRequester"],
        ("/users/workers", None): ["UsersManager.addWorker", "UsersManager.updateCapabilities"],
        ("/tasks", None): ["TasksManager.addTask"],
        ("/tasks/3/allocate", None): ["TasksManager.allocateTask"],
        ("/tasks/3/reviews", None): ["TasksManager.reviewOutcome"],
        ("/tasks/3/cancel", None): ["TasksManager.updateTaskStatus"],
        ("/tasks/3/cancel-open-slots", None): ["TasksManager.cancelOpenSlots"],
        ("/models/commitments", None): ["TasksManager.commitCid"],
        ("/models", "bafy"): ["TasksManager.commitCid", "ModelsManager.addModel"],
        ("/models/requests", None): ["ModelsManager.allocateModel"],
        ("/models/requests/3/reviews", None): ["ModelsManager.updateModelRep"],
    }
    for (path, cid), want in names.items():
        body = {"cid": cid} if cid else {}
        assert [c.name for c in expect_request("POST", path, body, me).calls] == want, path
    with pytest.raises(LookupError):
        expect_request("POST", "/users/workers/0xab/approval", {}, me)
    paid = expect_request("POST", "/tasks", {"num_workers": 3, "payment_wei": 7}, me).calls[0]
    assert paid.value == 21
    priced = expect_request("POST", "/models/requests", {"num_models": 2, "price_wei": 5}, me)
    assert priced.calls[0].value == 10
    assert Expect("x", (Call(UMC, "addRequester"),)).calls[0].value == 0
