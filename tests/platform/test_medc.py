"""MEDC on the embedded stack (issue 10, deliverable 7), through the CLI: a model is shared on
the MMC -> a new requester (its own key: every write signed locally and relayed) buys it as an
expert (allocateModel) while submitting a task -> the worker daemon pulls and verifies it and
trains with it (thesis Alg. 5.1, tiny budget) -> the outcome card lists the expert's CID and
the QoS the MMC gave it -> the requester's review moves the expert's reputation, on chain and
in the REST listing."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file
from typer.testing import CliRunner

from backend.chain.platform import cid_commitment, cid_hash
from backend.store.bundle import upload_model
from backend.store.staged import StagedUpload
from drlaas.cli import app
from drlaas.commands.up import running_platform
from workers.daemon.gateway import Gateway
from workers.daemon.keys import load_or_create_key
from workers.mdrl.review import REVIEW_EPISODES, review_experts
from workers.mdrl.trainingspec import TrainingSpec

from .conftest import worker_logs

EXPERT = Path(__file__).resolve().parents[2] / "models" / "odmtl-2a"  # fits a 6x6 2-agent task


def test_medc_task_with_an_mmc_expert_end_to_end(data_dir: Path, tmp_path: Path) -> None:
    cli = CliRunner()

    def run(*args: str) -> dict:
        res = cli.invoke(app, [*args, "--gateway", p.url, "--json"])
        assert res.exit_code == 0, f"{args}: {res.output}\n{worker_logs(p)}"
        return json.loads(res.stdout)

    with running_platform(workers=1, data_dir=data_dir) as p:
        p.wait_registered()
        # the worker shares a model of its own (an upload, not an outcome)
        owner_key = next((p.data_dir / "keys").glob("*.key"))
        pushed = run("model", "push", str(EXPERT), "--key", str(owner_key))  # commit, upload
        cid = pushed["cid"]
        assert cid == upload_model(StagedUpload(), EXPERT)  # the CID an IPFS node gives
        owner = load_or_create_key(owner_key).address
        committed_at = p.chain.platform.tmc.call(
            "cidCommits", cid_commitment(cid, owner)
        )
        assert committed_at and "0x" + cid_commitment(cid, owner).hex() == pushed["commitment"]
        env = json.loads((EXPERT / "model.json").read_text())["env"]
        shared = run(
            "model", "share", "--key", str(owner_key), "--cid", cid, "--env", json.dumps(env)
        )
        assert "events" in shared or shared.get("cid") == cid

        # a requester with a fresh key buys one expert from the MMC and submits the task
        req = tmp_path / "requester.key"
        run("requester", "register", "--key", str(req))
        out = cli.invoke(
            app,
            [
                "task",
                "submit",
                "--key",
                str(req),
                "--grid",
                "6x6",
                "--agents",
                "2",
                "--steps",
                "1900",
                "--minutes",
                "3",
                "--seed",
                "5",
                "--payment-wei",
                str(10**15),
                "--deadline-s",
                "3600",
                "--experts-from-mmc",
                "1",
                "--expert-rate",
                "0.5",
                "--gateway",
                p.url,
                "--json",
            ],
        )
        assert out.exit_code == 0, out.output
        task = json.loads(out.stdout)
        alloc_id = task["expert_allocation"]
        alloc = run("model", "allocation", str(alloc_id))
        assert [m["cid"] for m in alloc["models"]] == [cid]
        model_id, qos = alloc["models"][0]["id"], alloc["models"][0]["qos"]
        assert qos > 0

        run("task", "wait", str(task["task_id"]), "--timeout", "240")
        pulled = run(  # sealed to the requester (task submit's default): opened with its key
            "task", "pull", str(task["task_id"]), "--key", str(req), "--out", str(tmp_path / "o")
        )
        card = json.loads((Path(pulled["path"]) / "model.json").read_text())
        used = card["training"]["experts"]
        assert [(e["ref"], e["qos"]) for e in used["experts"]] == [(cid, qos)]
        assert used["rate"] == 0.5 and used["experts"][0]["episodes"] > 0
        # the worker fetched the expert into the job directory, and removed it once submitted
        (job,) = (p.data_dir / "workers").glob(f"*/jobs/*/{task['task_id']}")
        assert json.loads((job / "state.json").read_text())["experts"] == [cid]
        assert not (job / "experts").exists()
        # the worker's trial of the expert on the task after the run: the requester's evidence,
        # the same figures as the expert followed by the team on the same episodes here
        tid = str(task["task_id"])
        shown = cli.invoke(app, ["task", "show", tid, "--spec", "--gateway", p.url])
        assert shown.exit_code == 0, shown.output
        expected = review_experts(
            [(cid, str(EXPERT))], TrainingSpec.from_dict(json.loads(shown.stdout)).env
        )
        assert used["review"] == json.loads(json.dumps(expected))
        (trial,) = used["review"]["experts"]
        assert used["review"]["episodes"] == REVIEW_EPISODES and trial["ref"] == cid
        suggested = trial["suggested_review"]
        assert 0 <= suggested <= 5 and trial["time"] >= used["review"]["oracle_time"]

        # the requester reviews the expert it used, as the worker's trial suggests
        mmc = p.chain.platform.mmc
        before = mmc.contract.functions.getModel(model_id).call()[0]
        run(
            "model",
            "review",
            str(alloc_id),
            "--model",
            str(model_id),
            "--review",
            str(suggested),
            "--key",
            str(req),
        )
        after = mmc.contract.functions.getModel(model_id).call()[0]
        assert (before[-1], after[-1]) == (0, suggested)  # totalReview on chain
        assert int(mmc.contract.functions.modelOfCid(cid_hash(cid)).call()) == model_id
        anon = Gateway(p.url)
        listed = {m["id"]: m for m in anon.get("/models")["data"]}
        # Eq. 11: review / (1 * 5)
        assert listed[model_id]["reputation"] == pytest.approx(suggested / 5)
        experts = anon.get(f"/tasks/{task['task_id']}")["experts"]
        assert [(e["cid"], e["alloc_id"], e["review"]) for e in experts] == [
            (cid, alloc_id, suggested)
        ]
        # the task page shows the trial from the outcome card (sealed: its card is plain text)
        (shown_trial,) = experts[0]["trials"]
        (outcome,) = anon.get(f"/tasks/{task['task_id']}")["outcomes"]
        assert shown_trial == {
            "worker": outcome["worker"], "episodes": REVIEW_EPISODES,
            **{k: trial[k] for k in ("success", "time", "time_vs_oracle", "suggested_review")},
        }
        assert experts[0]["suggested_review"] == trial["suggested_review"]  # one trial's own
        shown = cli.invoke(app, ["task", "show", str(task["task_id"]), "--gateway", p.url])
        assert shown.exit_code == 0 and "experts" in shown.stdout and cid[:20] in shown.stdout
        assert "SUGGESTED (TRIAL)" in shown.stdout and f"{suggested}/5 (" in shown.stdout
        # the spec document alone (for `drlaas train --task`): the one the chain's CID names
        spec = cli.invoke(app, ["task", "show", str(task["task_id"]), "--spec", "--gateway", p.url])
        assert spec.exit_code == 0, spec.output
        doc = json.loads(spec.stdout)
        assert TrainingSpec.from_dict(doc).experts == (cid,)

        # ... trained on a laptop: the expert fetched by CID through the gateway and verified,
        # the same weights as the worker's outcome, the card naming the expert by its CID
        (tmp_path / "task.json").write_text(spec.stdout)
        local_env = {"DRLAAS_GATEWAY": p.url, "DRLAAS_CACHE": str(tmp_path / "cache")}
        res = cli.invoke(app, ["train", "--task", str(tmp_path / "task.json"), "--out",
                               str(tmp_path / "local"), "--no-progress", "--no-tensorboard"],
                         env=local_env)
        assert res.exit_code == 0, res.output
        assert (tmp_path / "cache" / "experts" / cid / "model.json").is_file()
        local = tmp_path / "local" / "model"
        assert [e["ref"] for e in json.loads((local / "model.json").read_text())["training"][
            "experts"]["experts"]] == [cid]
        mine = load_file(local / "model.safetensors")
        theirs = load_file(Path(pulled["path"]) / "model.safetensors")
        assert mine.keys() == theirs.keys() and all(torch.equal(mine[k], theirs[k]) for k in mine)
        # a CID the platform does not hold, and an unreachable gateway: named, nothing trained
        missing = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
        for env_vars, msg in ((local_env, missing), ({**local_env, "DRLAAS_GATEWAY":
                              "http://127.0.0.1:9"}, "cannot fetch it from the gateway")):
            res = cli.invoke(app, ["train", "--preset", "odmtl-2a-10x10", "--steps", "64",
                                   "--experts", missing, "--out", str(tmp_path / "never")],
                             env=env_vars)
            text = " ".join(res.output.replace("│", " ").split())
            assert res.exit_code == 2 and msg in text, res.output
        assert not (tmp_path / "never").exists()
        anon.close()
