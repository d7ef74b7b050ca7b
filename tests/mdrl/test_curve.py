"""The training curve of a model card (workers/mdrl/curve.py) and the worker's card carrying it."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from workers.mdrl.curve import MAX_CURVE_POINTS, attach_curve, training_curve

COLUMNS = ["update", "global_step", "wall_time", "success", "episode_length", "episode_cost"]


def write_metrics(path: Path, rows: list[list[object]]) -> Path:
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(COLUMNS)
        w.writerows(rows)
    return path


def test_short_run_keeps_every_update_and_drops_nan(tmp_path: Path) -> None:
    rows = [
        [1, 100, 0.5, 0.25, 40.0, 60.0],
        [2, 200, 1.0, "", "", ""],  # no episode finished in this update
        [3, 300, 1.5, 0.5, "nan", 30.0],
        [2, 200, 1.1, 0.125, 35.0, 50.0],  # re-logged after a resume: the last row wins
    ]
    c = training_curve(write_metrics(tmp_path / "m.csv", rows))
    assert c["x"] == "env_steps" and c["updates"] == 3
    assert c["points"] == [
        {"step": 100, "wall_s": 0.5, "success": 0.25, "time": 40.0, "cost": 60.0},
        {"step": 200, "wall_s": 1.1, "success": 0.125, "time": 35.0, "cost": 50.0},
        {"step": 300, "wall_s": 1.5, "success": 0.5, "time": None, "cost": 30.0},
    ]


def test_long_run_is_bucketed_to_the_bound_and_ends_at_the_last_step(tmp_path: Path) -> None:
    n = 1000
    rows = [[i, 64 * i, i / 10, (i % 2) * 1.0, float(i), 2.0 * i] for i in range(1, n + 1)]
    c = training_curve(write_metrics(tmp_path / "m.csv", rows))
    pts = c["points"]
    assert c["updates"] == n and len(pts) == MAX_CURVE_POINTS
    assert pts[-1]["step"] == 64 * n and pts[-1]["wall_s"] == n / 10
    assert [p["step"] for p in pts] == sorted({p["step"] for p in pts})
    # 1000 / 200 = 5 updates per bucket: the first holds updates 1-5
    assert pts[0]["step"] == 5 * 64
    assert pts[0]["time"] == pytest.approx(3.0) and pts[0]["cost"] == pytest.approx(6.0)
    assert pts[0]["success"] == pytest.approx(0.6)  # updates 1, 3, 5 succeeded


def test_worker_job_card_carries_the_curve(tmp_path: Path) -> None:
    from workers.daemon.job import run_job
    from workers.mdrl.trainingspec import TrainingSpec

    spec = TrainingSpec.from_dict(
        {
            "env": {"rows": 5, "cols": 5, "agents": 1},
            "observation": {"kind": "odmtl", "window": 3},
            "algorithm": {"ppo": {"num_envs": 4, "horizon": 32, "update_epochs": 1}},
            "budget": {"steps": 3 * 128},
            "seed": 1,
        }
    )
    model, _ = run_job(spec, tmp_path / "job")
    card = json.loads((model / "model.json").read_text())
    posted = [json.loads(line) for line in (tmp_path / "job" / "progress.jsonl").open()]
    pts = card["curve"]["points"]
    assert card["curve"]["updates"] == len(posted) == 384 // 32  # horizon 32 steps per update
    assert [p["step"] for p in pts] == [p["step"] for p in posted] == list(range(32, 385, 32))
    for mine, live in zip(pts, posted, strict=True):  # same figures as the live curve
        for key in ("success", "time", "cost"):
            assert (mine[key] is None) == (live[key] is None)
            assert mine[key] is None or mine[key] == pytest.approx(live[key], abs=1e-4)
    assert pts[-1]["step"] == card["training"]["env_steps"]
    assert all(p["wall_s"] > 0 for p in pts)


def test_attach_curve_without_metrics_leaves_the_card(tmp_path: Path) -> None:
    (tmp_path / "model.json").write_text('{"format": "drlaas-model/1"}')
    assert attach_curve(tmp_path, tmp_path / "missing.csv") is False
    assert json.loads((tmp_path / "model.json").read_text()) == {"format": "drlaas-model/1"}


def test_zoo_cards_are_completed_with_baselines_and_their_own_runs_curve(tmp_path: Path) -> None:
    from workers.mdrl.baselines import make_baseline
    from workers.mdrl.evaluate import evaluate
    from workers.mdrl.spec import EnvSpec
    from workers.mdrl.zoo import BASELINE_POLICIES, add_baselines, attach_run_curve

    env = EnvSpec(rows=5, cols=5, agents=2)
    mine = {"success": 1.0, "time": 3.0, "oracle_time": 2.0}
    card = {"env": env.to_dict(), "training": {"env_steps": 300},
            "zoo": {"heldout": {"episodes": 12, "seed": 5, "poisson": dict(mine),
                                "expected": dict(mine)}}}  # fmt: skip
    (tmp_path / "model.json").write_text(json.dumps(card))
    held = add_baselines(tmp_path)
    for readings in ("poisson", "expected"):
        assert held[readings]["time"] == 3.0  # the model's own figures are kept
        assert list(held[readings]["baselines"]) == list(BASELINE_POLICIES)
        for name, figures in held[readings]["baselines"].items():
            direct = evaluate(make_baseline(name), env.replace(readings=readings), 12, seed=5)
            assert figures["time"] == direct.summary["time_mean"]
            assert figures["success"] == direct.summary["success_rate"]
    assert json.loads((tmp_path / "model.json").read_text())["zoo"]["heldout"] == held

    run = tmp_path / "run"
    run.mkdir()
    write_metrics(run / "metrics.csv", [[1, 100, 0.5, 0.0, 9.0, 9.0], [2, 200, 1.0, 1.0, 5, 6]])
    with pytest.raises(ValueError, match="not this model's run"):
        attach_run_curve(tmp_path, run)  # ends at 200 steps, the card says 300
    write_metrics(run / "metrics.csv", [[1, 150, 0.5, 0.0, 9.0, 9.0], [2, 300, 1.0, 1.0, 5, 6]])
    assert [p["step"] for p in attach_run_curve(tmp_path, run)["points"]] == [150, 300]
    assert json.loads((tmp_path / "model.json").read_text())["curve"]["updates"] == 2
