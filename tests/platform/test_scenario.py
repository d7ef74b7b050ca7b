"""The issue-4 scenario on the embedded stack: gateway + chain + indexer + 3 worker processes,
driven through REST only (drlaas.commands.scenario)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from backend.store.bundle import pull_model, read_bundle
from drlaas.commands.client import model_app, task_app, worker_app
from drlaas.commands.scenario import ZOO_DIR, run_scenario
from drlaas.commands.up import running_platform
from workers.daemon.links import open_store
from workers.mdrl.modelio import load_model

from .conftest import worker_logs


def test_scenario_end_to_end(
    data_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    lines: list[str] = []
    monkeypatch.setenv("DRLAAS_DATA_DIR", str(data_dir))  # the CLI's `model pull` reads the store
    with running_platform(workers=3, data_dir=data_dir) as p:
        p.wait_registered()
        # an owner lists at most 4 models, fewer than the zoo needs from three workers: the
        # case that broke `make demo` once the zoo outgrew 3 x 8 models
        limit = 4
        p.chain.platform.mmc.set_max_models_per_owner(p.chain.platform.admin, limit)
        try:
            report = run_scenario(
                p.url, p.data_dir, steps=2000, timeout=240, say=lines.append, zoo=ZOO_DIR
            )
        except Exception as exc:
            raise AssertionError(f"{exc}\n{worker_logs(p)}") from exc
        tmc = p.chain.platform.tmc
        submitted = tmc.contract.events.OutcomeSubmitted().get_logs(from_block=0)
        store = open_store(p.settings)
        # the CID on chain is the worker's manifest, and it pulls into a loadable model
        assert [e["args"]["cid"] for e in submitted] == [report["cid"], report["medc"]["cid"]]
        assert submitted[0]["args"]["worker"] == report["worker"] in report["offered"]
        assert set(read_bundle(store, report["cid"])) == {
            "model.safetensors",
            "model.json",
        }
        policy = load_model(pull_model(store, report["cid"], tmp_path / "model"))
        assert policy.card["env"]["agents"] == 2
        # the CLI sees the same state through REST
        cli, url = CliRunner(), ["--gateway", p.url]
        shown = cli.invoke(task_app, ["show", str(report["task_id"]), "--json", *url])
        assert shown.exit_code == 0, shown.output
        assert json.loads(shown.output)["outcomes"][0]["cid"] == report["cid"]
        listed = cli.invoke(model_app, ["list", *url])
        assert listed.exit_code == 0 and report["cid"][:20] in listed.output
        pulled = cli.invoke(
            model_app, ["pull", str(report["model_id"]), "--out", str(tmp_path / "cli-model"), *url]
        )
        assert pulled.exit_code == 0, pulled.output
        assert load_model(tmp_path / "cli-model").card["env"]["rows"] == 6
        status = cli.invoke(worker_app, ["status", report["worker"], "--json", *url])
        assert json.loads(status.output)["reputation"] == report["reputation_after"]
        # the whole shipped zoo is listed, more models than the workers may own together
        # (MMC maxModelsPerOwner): the scenario adds publisher accounts when they are full
        policies = {
            c.parent.name
            for c in ZOO_DIR.glob("*/model.json")
            if "kind" not in json.loads(c.read_text())
        }
        assert len(policies) > 3 * limit
        assert set(report["zoo"]) == policies
        added = p.chain.platform.mmc.contract.events.ModelAdded().get_logs(from_block=0)
        owned: dict[str, int] = {}
        for e in added:
            owned[e["args"]["owner"]] = owned.get(e["args"]["owner"], 0) + 1
        assert len(added) == 1 + len(policies) and max(owned.values()) <= limit
    assert report["progress_points"] >= 3  # the curve was visible while it trained
    assert report["reputation_after"] > report["reputation_before"]
    assert report["allocated"] == [report["cid"]]
    # MEDC: the second task trained with the allocated model and its card says so; the
    # requester's review of the expert, the one the worker's trial suggests, moved the model's
    # reputation (Eq. 11: review / (1 * 5))
    medc = report["medc"]
    assert [e["ref"] for e in medc["experts"]] == [report["cid"]]
    assert medc["experts"][0]["episodes"] > 0
    trial = medc["expert_trial"]
    assert trial["ref"] == report["cid"] and 0 <= medc["expert_review"] <= 5
    assert medc["expert_review"] == trial["suggested_review"]
    assert medc["expert_reputation"][1] == pytest.approx(medc["expert_review"] / 5)
    assert medc["cid"] != report["cid"]
    # the MEDC task asks for the best evaluated policy: the outcome's card says when it was kept
    assert medc["selected"]["by"] == "time" and medc["selected"]["update"] >= 1
    assert 0 < medc["selected"]["global_step"] <= 2000  # the budget of the test's tasks
    assert any("progress" in ln for ln in lines)
