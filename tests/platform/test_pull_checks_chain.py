"""`model pull ID` against a hostile gateway (the fake one of test_hostile_gateway_client.py,
whose JSON-RPC is an embedded chain with the platform deployed): the CID the gateway names for
a model id is pulled only if the MMC lists it for that id, else a one-line error and nothing
written. The tables and summaries of a hostile gateway's answers never end in a traceback."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner
from web3 import Web3

from backend.store import EmbeddedStore
from backend.store.bundle import upload_model
from backend.store.dag import compute_cid
from drlaas.cli import app
from drlaas.commands.client.txcheck import MMC, TMC, UMC

from .test_hostile_gateway_client import EXPERT, Fake
from .test_hostile_gateway_client import fake as fake  # noqa: PLC0414 - the fixture, shared

OTHER = EXPERT.parent / "odmtl-3a"  # another valid bundle the gateway could hand out


def serve_chain(fake: Fake, chain: Any, p: Any) -> None:
    """The fake gateway's deployment is ``p`` and its /rpc the embedded ``chain``'s."""
    fake.contracts = {UMC: p.umc.address, TMC: p.tmc.address, MMC: p.mmc.address,
                      "chain_id": chain.chain_id, "rpc": "/rpc"}

    def rpc(f: Fake, body: Any) -> tuple[int, Any]:
        if body["method"] == "eth_chainId":
            result = hex(chain.chain_id)
        else:
            assert body["method"] == "eth_call"
            tx, block = body["params"]
            to = Web3.to_checksum_address(tx["to"])
            result = "0x" + bytes(chain.w3.eth.call({"to": to, "data": tx["data"]}, block)).hex()
        return 200, {"jsonrpc": "2.0", "id": body["id"], "result": result}

    fake.routes["/rpc"] = rpc


@pytest.fixture
def listed(fake: Fake, chain: Any, env: Any, tmp_path: Path) -> tuple[int, str, str]:
    """(model id, its CID on chain, another bundle's CID), both bundles in the fake's store."""
    p, actors, _ = env
    store = EmbeddedStore(tmp_path / "ipfs", fsync=False)
    cid, other = upload_model(store, EXPERT), upload_model(store, OTHER)
    model_id, _ = p.mmc.add_model(actors.workers[0], cid, 0, [6, 6, 2])
    serve_chain(fake, chain, p)
    fake.routes["/api/blocks/*"] = lambda f, b: (200, store.get(f.seen[-1][1].split("/")[-1]))
    return model_id, cid, other


def pull(fake: Fake, model: str, out: Path, *extra: str) -> Any:
    return CliRunner().invoke(app, ["model", "pull", model, "--gateway", fake.url,
                                    "--out", str(out), *extra])


def test_model_pull_refuses_another_bundle_under_a_listed_id(
    fake: Fake, listed: tuple[int, str, str], tmp_path: Path
) -> None:
    model_id, cid, other = listed
    named = {"cid": other}
    fake.routes[f"/api/models/{model_id}"] = lambda f, b: (200, {"id": model_id, **named})
    out = tmp_path / "out"
    out.mkdir()  # an empty folder: nothing may be written into it
    res = pull(fake, str(model_id), out)
    assert res.exit_code == 1, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), res.output
    assert f"names {other} as model {model_id}'s CID, but the chain lists {cid} as its CID" in (
        lines[0])
    assert not any(out.iterdir()) and not list(tmp_path.glob(".out.pulling-*"))
    assert not any(p.startswith("/api/blocks/") for _, p, _ in fake.seen)
    named["cid"] = cid  # the CID the chain lists: pulled
    res = pull(fake, str(model_id), out)
    assert res.exit_code == 0, res.output
    weights = (out / "model.safetensors").read_bytes()
    assert compute_cid(weights) == compute_cid((EXPERT / "model.safetensors").read_bytes())


def test_model_pull_refuses_a_model_id_the_chain_does_not_list(
    fake: Fake, listed: tuple[int, str, str], tmp_path: Path
) -> None:
    _, cid, _ = listed
    fake.routes["/api/models/99"] = lambda f, b: (200, {"id": 99, "cid": cid})
    res = pull(fake, "99", tmp_path / "out")
    assert res.exit_code == 1, res.output
    assert f"names {cid} as model 99's CID, but the chain lists no model with that id" in (
        res.output)
    assert not (tmp_path / "out").exists()


def test_model_pull_names_a_gateway_answer_without_a_cid(fake: Fake, tmp_path: Path) -> None:
    fake.routes["/api/models/3"] = lambda f, b: (200, {"id": 3})
    res = pull(fake, "3", tmp_path / "out")
    assert res.exit_code == 1 and "'cid' is not a string" in res.output, res.output
    assert not (tmp_path / "out").exists()


def invoke(fake: Fake, *args: str) -> Any:
    res = CliRunner().invoke(app, [*args, "--gateway", fake.url])
    assert not isinstance(res.exception, LookupError | TypeError | ValueError | AttributeError), (
        res.exception)
    return res


def test_task_list_shows_an_environment_of_another_shape_as_unknown(fake: Fake) -> None:
    tasks = [
        {"id": 1, "status": "open", "env": {"rows": 6, "cols": 6}},  # no walls, intensity
        {"id": 2, "status": "open", "env": {"walls": "ab", "intensity": {"values": ["x"]}}},
        "not a task",
    ]
    fake.routes["/api/tasks"] = lambda f, b: (200, {"data": tasks, "count": 3})
    res = invoke(fake, "task", "list")
    assert res.exit_code == 0, res.output
    rows = res.output.splitlines()[2:]
    assert [r.split()[:3] for r in rows] == [["1", "open", "?"], ["2", "open", "?"]]


def test_model_show_shows_figures_of_another_shape_as_unknown(fake: Fake) -> None:
    model = {"id": 5, "cid": "bafy", "produced_by": {"task_id": 3},
             "experts": [{"ref": "bafx"}, 7], "heldout": {"readings": [{"success": "high"}]},
             "final_eval": {"success": None}, "curve": [{"success": 0.5}]}
    fake.routes["/api/models/5"] = lambda f, b: (200, model)
    res = invoke(fake, "model", "show", "5")
    assert res.exit_code == 0, res.output
    assert "produced by task 3 (worker ?;" in res.output
    assert "expert bafx (not listed here; from the ?)" in res.output
    assert "held-out (? episodes, ? readings): success ?" in res.output
    assert "curve: 1 points to ? env steps" in res.output


def test_an_answer_of_another_shape_is_a_one_line_error(fake: Fake) -> None:
    fake.routes["/api/models/requests/1"] = lambda f, b: (200, {"models": []})  # no alloc_id
    res = invoke(fake, "model", "allocation", "1")
    assert res.exit_code == 1, res.output
    lines = res.output.strip().splitlines()
    assert len(lines) == 1, res.output
    line = lines[0]
    assert line.startswith("error: the gateway's answer lacks what this command shows")
