"""The shipped zoo (models/): every model loads, runs, and its card's held-out figures hold
on fresh episodes."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from statistics import NormalDist

import pytest

from workers.mdrl.evaluate import evaluate
from workers.mdrl.modelio import load_model
from workers.mdrl.zoo import HELDOUT_SEED, READING_MODELS, ZOO

MODELS = Path(__file__).resolve().parents[2] / "models"
SHIPPED = sorted(p.parent.name for p in MODELS.glob("*/model.json")
                 if "kind" not in json.loads(p.read_text()))  # policies, not the walls CAE
FRESH_SEED = HELDOUT_SEED + 1  # other episodes than the card's
Z95 = NormalDist().inv_cdf(0.975)
CHECKS = len(SHIPPED) * len(READING_MODELS) * 3  # success, time and cost of each
Z_FAMILY = NormalDist().inv_cdf(1 - 0.01 / (2 * CHECKS))
"""Two-sided 1% for the whole family of checks (Bonferroni, ~4 standard errors): at 1% per
check, ~200 checks fail an honest card now and then by chance alone (seen: a 1000-episode card
1.4 SE high against a fresh 200-episode sample 1.9 SE low, the same model's mean on 3000 other
episodes between the two)."""


def test_every_zoo_entry_is_shipped():
    assert set(ZOO) <= set(SHIPPED), f"missing from models/: {sorted(set(ZOO) - set(SHIPPED))}"


@pytest.mark.parametrize("name", SHIPPED)
def test_card_figures_hold_on_200_fresh_episodes(name):
    policy = load_model(MODELS / name)
    card = json.loads((MODELS / name / "model.json").read_text())
    zoo = card["zoo"]
    assert zoo["env_steps"] > 0 and zoo["wall_clock_s"] > 0 and zoo["preset"]
    for readings in READING_MODELS:
        claimed = zoo["heldout"][readings]
        spec = policy.env_spec.replace(readings=readings)
        fresh = evaluate(policy, spec, 200, seed=FRESH_SEED).summary
        p = claimed["success"]
        # interval of the difference of two independent proportions (1000 vs 200 episodes)
        assert abs(p - fresh["success_rate"]) <= Z_FAMILY * math.sqrt(
            max(p * (1 - p), 1e-3) * (1 / 1000 + 1 / 200)
        )
        if p < 0.995:
            # failures run to the 100-step cap: time and cost are then a heavy-tailed mixture
            # that a t interval does not cover; success is the claim that matters there
            continue
        for key in ("time", "cost"):
            # interval of the difference of two independent means (card: 1000 episodes,
            # fresh: 200): the card's claim must be consistent with what the model does now
            lo, hi = fresh[f"{key}_ci"]
            c_lo, c_hi = claimed[f"{key}_ci"]
            half = Z_FAMILY / Z95 * math.hypot((hi - lo) / 2, (c_hi - c_lo) / 2)
            assert abs(claimed[key] - fresh[f"{key}_mean"]) <= half, (
                f"{name} {readings} {key}: card {claimed[key]:.2f}, fresh "
                f"{fresh[f'{key}_mean']:.2f} ± {half:.2f}"
            )


def test_a_zoo_entry_with_experts_trains_under_them_and_resumes_with_them(tmp_path, monkeypatch):
    """An entry's experts (zoo names) guide its run (MEDC), are listed on the card, and a
    resumed run keeps them and their counts."""
    import shutil

    from workers.mdrl import zoo

    models = tmp_path / "models"
    for name in ("ch4-a1w0-10x10", "ch4-a2w2-10x10"):
        shutil.copytree(MODELS / name, models / name)
    steps = 8192  # one update of the preset
    monkeypatch.setitem(zoo.ZOO, "guided", zoo.ZooEntry(
        "ch4-a3w3-sparse-10x10", minutes=5, steps=steps,
        experts=("ch4-a1w0-10x10", "ch4-a2w2-10x10")))
    monkeypatch.setattr(zoo, "heldout", lambda policy, spec: {"episodes": 0})

    def experts_of(target: Path) -> dict:
        return json.loads((target / "model.json").read_text())["training"]["experts"]

    first = experts_of(zoo.train_entry("guided", models, tmp_path / "runs"))
    assert first["method"] == "MEDC (Alg. 5.1)"
    assert [e["ref"] for e in first["experts"]] == [str(models / n) for n in
                                                    ("ch4-a1w0-10x10", "ch4-a2w2-10x10")]
    guided = sum(e["episodes"] for e in first["experts"])
    assert guided > 0 and first["own_episodes"] > 0

    monkeypatch.setitem(zoo.ZOO, "guided", dataclasses.replace(zoo.ZOO["guided"], steps=2 * steps))
    target = zoo.train_entry("guided", models, tmp_path / "runs")
    again = experts_of(target)
    assert json.loads((target / "model.json").read_text())["zoo"]["env_steps"] == 2 * steps
    assert [e["ref"] for e in again["experts"]] == [e["ref"] for e in first["experts"]]
    assert sum(e["episodes"] for e in again["experts"]) > guided  # counts carried over, grown


def test_a_zoo_entry_can_fine_tune_an_earlier_entry(tmp_path, monkeypatch):
    """``init_from`` starts the run from an earlier zoo model's weights, with the entry's own
    PPO changes and a built-in expert; the card names the model it started from."""
    import shutil

    import torch
    from safetensors.torch import load_file

    from workers.mdrl import zoo

    models = tmp_path / "models"
    shutil.copytree(MODELS / "ch4-a3w3-10x10", models / "ch4-a3w3-10x10")
    monkeypatch.setitem(zoo.ZOO, "tuned", zoo.ZooEntry(
        "ch4-a3w3-sr-10x10", minutes=5, steps=8192, init_from="ch4-a3w3-10x10",
        experts=("oracle",), expert_rate=0.3, ppo=(("learning_rate", 1e-6),)))
    monkeypatch.setattr(zoo, "heldout", lambda policy, spec: {"episodes": 0})
    target = zoo.train_entry("tuned", models, tmp_path / "runs")
    card = json.loads((target / "model.json").read_text())
    assert card["training"]["init_from"]["ref"] == str(models / "ch4-a3w3-10x10")
    assert card["training"]["ppo"]["learning_rate"] == 1e-6
    experts = card["training"]["experts"]
    assert [e["ref"] for e in experts["experts"]] == ["oracle"] and experts["rate"] == 0.3
    # one update at a tiny learning rate: still (nearly) the weights it started from
    start = load_file(str(models / "ch4-a3w3-10x10" / "model.safetensors"))
    tuned = load_file(str(target / "model.safetensors"))
    assert set(start) == set(tuned)
    assert all(torch.allclose(start[k], tuned[k], atol=1e-3) for k in start)
    assert any(not torch.equal(start[k], tuned[k]) for k in start)


def test_a_finished_run_of_an_entry_is_published_and_another_is_refused(tmp_path, monkeypatch):
    """``drlaas zoo publish NAME --run DIR``: a `drlaas train` run of the entry's preset, seed
    and experts becomes models/NAME with the zoo section and the run's curve; a run of another
    set-up is refused naming what differs."""
    import shutil

    from typer.testing import CliRunner

    from workers.mdrl import zoo
    from workers.mdrl.commands.zoo import app

    models = tmp_path / "models"
    shutil.copytree(MODELS / "ch4-a1w0-10x10", models / "ch4-a1w0-10x10")
    monkeypatch.setitem(zoo.ZOO, "pub", zoo.ZooEntry(
        "ch4-a3w3-sr-10x10", minutes=5, seed=3, experts=("ch4-a1w0-10x10",)))
    figures = {"success": 1.0, "time": 4.0, "cost": 5.0, "oracle_time": 3.0}
    monkeypatch.setattr(zoo, "heldout", lambda policy, spec: {
        "episodes": spec.rows, "poisson": figures, "expected": figures})
    import typer

    from workers.mdrl.commands.train import train as train_cmd

    cli = typer.Typer()
    cli.command()(train_cmd)
    cli.command("noop")(lambda: None)
    runner = CliRunner()
    expert = str(models / "ch4-a1w0-10x10")
    for out, seed in (("good", "3"), ("other-seed", "4")):
        res = runner.invoke(cli, ["train", "--preset", "ch4-a3w3-sr-10x10", "--steps", "8192",
                                  "--seed", seed, "--experts", expert, "--no-progress",
                                  "--out", str(tmp_path / out)])
        assert res.exit_code == 0, res.output
    res = runner.invoke(app, ["publish", "pub", "--run", str(tmp_path / "good"),
                              "--models", str(models)])
    assert res.exit_code == 0, res.output
    card = json.loads((models / "pub" / "model.json").read_text())
    assert card["zoo"]["env_steps"] == 8192 and card["zoo"]["seed"] == 3
    assert card["zoo"]["heldout"]["episodes"] == 10  # evaluated on the entry's env
    assert json.loads(res.output.strip().splitlines()[-1])["poisson"]["time"] == 4.0
    assert [p["step"] for p in card["curve"]["points"]] == [8192]
    res = runner.invoke(app, ["publish", "pub", "--run", str(tmp_path / "other-seed"),
                              "--models", str(models)])
    assert res.exit_code == 2
    assert "seed" in " ".join(res.output.replace("│", " ").split())
    res = runner.invoke(app, ["publish", "pub", "--run", str(tmp_path / "missing"),
                              "--models", str(models)])
    assert res.exit_code == 2 and "no finished run" in res.output
    # a damaged card is named; a publish that fails midway leaves the published model whole
    published = (models / "pub" / "model.json").read_text()
    shutil.copytree(tmp_path / "good", tmp_path / "damaged")
    (tmp_path / "damaged" / "model" / "model.json").write_text("{not json")
    res = runner.invoke(app, ["publish", "pub", "--run", str(tmp_path / "damaged"),
                              "--models", str(models)])
    flat = "".join(res.output.replace("│", " ").split())
    assert res.exit_code == 2 and "damaged/model/model.json" in flat, res.output

    def interrupted(policy, spec):
        raise KeyboardInterrupt

    monkeypatch.setattr(zoo, "heldout", interrupted)
    res = runner.invoke(app, ["publish", "pub", "--run", str(tmp_path / "good"),
                              "--models", str(models)])
    assert res.exit_code != 0
    assert (models / "pub" / "model.json").read_text() == published
    assert sorted(x.name for x in models.iterdir()) == ["ch4-a1w0-10x10", "pub"]


def test_zoo_list_and_complete_name_a_malformed_card(tmp_path):
    """One damaged card does not hide the others from ``zoo list`` (it is named in its row);
    ``zoo complete`` of it is a usage error naming the directory; a missing zoo is named."""
    from typer.testing import CliRunner

    from workers.mdrl.commands.zoo import app

    (tmp_path / "odmtl-2a").mkdir()
    (tmp_path / "odmtl-2a" / "model.json").write_text('{"zoo": {"heldout": ')
    runner = CliRunner()
    res = runner.invoke(app, ["list", "--models", str(tmp_path)])
    assert res.exit_code == 0, res.output
    rows = {line.split()[0]: line for line in res.output.splitlines() if line.strip()}
    assert set(rows) == set(ZOO) and "unreadable card" in rows["odmtl-2a"]
    res = runner.invoke(app, ["complete", "odmtl-2a", "--models", str(tmp_path)])
    assert res.exit_code == 2 and "cannot complete its" in res.output, res.output
    res = runner.invoke(app, ["list", "--models", str(tmp_path / "none")])
    said = " ".join(res.output.replace("│", " ").split())
    assert res.exit_code == 2 and "no such directory" in said, res.output


def test_zoo_list_finds_the_shipped_models_from_any_directory(tmp_path, monkeypatch):
    """`drlaas zoo list` looked for ./models: outside the checkout it found no zoo (user
    audit). Without the shipped zoo the error names where it looked and --models."""
    from typer.testing import CliRunner

    from workers.mdrl.commands import zoo as zoo_commands

    monkeypatch.chdir(tmp_path)
    res = CliRunner().invoke(zoo_commands.app, ["list"])
    assert res.exit_code == 0, res.output
    rows = {line.split()[0]: line for line in res.output.splitlines() if line.strip()}
    assert set(rows) == set(ZOO) and "poisson: time" in rows["odmtl-2a"], res.output
    monkeypatch.setattr(zoo_commands, "SHIPPED_MODELS", tmp_path / "gone")
    res = CliRunner().invoke(zoo_commands.app, ["list"], env={"COLUMNS": "200"})
    said = " ".join(res.output.replace("│", " ").split())
    assert res.exit_code == 2 and str(tmp_path / "gone") in said and "--models DIR" in said, said
