"""The evaluation harness and the `eval` command."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import typer
from scipy import stats
from typer.testing import CliRunner

from workers.mdrl.baselines import BayesPolicy, OraclePolicy, RandomPolicy, UniformPolicy
from workers.mdrl.commands.evaluate import eval_command
from workers.mdrl.evaluate import compare, evaluate, t_interval, wilson_interval
from workers.mdrl.spec import EnvSpec

SPEC = EnvSpec(walls=(0, 2))


def _app() -> typer.Typer:
    app = typer.Typer()
    app.command("eval")(eval_command)

    @app.callback()
    def _root() -> None:  # keep `eval` a subcommand, as under `drlaas`
        pass

    return app


def test_wilson_interval_known_values():
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(3.8415 / 13.8415, abs=1e-4)
    lo, hi = wilson_interval(10, 10)
    assert hi == 1.0 and lo == pytest.approx(1 - 3.8415 / 13.8415, abs=1e-4)
    lo, hi = wilson_interval(50, 100)
    assert (lo, hi) == pytest.approx((0.4038, 0.5962), abs=1e-4)


def test_t_interval_matches_scipy():
    x = np.random.default_rng(0).poisson(7.0, size=57).astype(float)
    expected = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=stats.sem(x))
    assert t_interval(x) == pytest.approx(expected)
    assert all(math.isnan(v) for v in t_interval(np.array([3.0])))


def test_same_seed_same_report_and_same_episodes_across_policies():
    a = evaluate(RandomPolicy(seed=4), SPEC, episodes=70, seed=8, batch=32)
    b = evaluate(RandomPolicy(seed=4), SPEC, episodes=70, seed=8, batch=32)
    assert a.summary == b.summary
    for name in ("found", "time", "cost", "target", "lower_bound"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    u = evaluate(UniformPolicy(), SPEC, episodes=70, seed=8, batch=32)
    np.testing.assert_array_equal(u.target, a.target)  # same layouts, whatever the policy
    np.testing.assert_array_equal(u.lower_bound, a.lower_bound)
    other = evaluate(RandomPolicy(seed=4), SPEC, episodes=70, seed=9, batch=32)
    assert not np.array_equal(other.target, a.target)


def test_report_figures_follow_the_episode_arrays():
    r = evaluate(RandomPolicy(seed=1), EnvSpec(max_steps=15), episodes=60, seed=0)
    assert r.episodes == 60
    assert 0 < r.found.sum() < 60  # some failures with only 15 steps
    assert r.success_rate == pytest.approx(r.found.mean())
    assert r.time[~r.found].tolist() == [15] * int((~r.found).sum())  # failures count max_steps
    assert r.time_mean == pytest.approx(r.time.mean())
    assert r.summary["time_mean_success"] == pytest.approx(r.time[r.found].mean())
    assert r.summary["cost_mean_success"] == pytest.approx(r.cost[r.found].mean())
    lo, hi = r.summary["cost_ci"]
    assert lo < r.cost_mean < hi
    assert (r.cost <= r.time * 3).all() and (r.cost >= 0).all()
    d = r.to_dict(per_episode=True)
    assert json.loads(json.dumps(d))["time"] == r.time.tolist()


def test_compare_ratios_against_oracle():
    oracle = evaluate(OraclePolicy(), SPEC, episodes=80, seed=3)
    bayes = evaluate(BayesPolicy(), SPEC, episodes=80, seed=3)
    same = compare(oracle, oracle)
    assert same.time_ratio == 1.0 and same.cost_ratio == 1.0
    c = compare(bayes, oracle)
    assert c.time_ratio == pytest.approx(bayes.time.mean() / oracle.time.mean())
    assert c.cost_ratio == pytest.approx(bayes.cost.mean() / oracle.cost.mean())
    assert c.time_ratio >= 1.0 and c.cost_ratio >= 1.0  # nobody beats the lower bound
    assert c.time_ratio_ci[0] <= c.time_ratio <= c.time_ratio_ci[1]
    elsewhere = evaluate(OraclePolicy(), SPEC, episodes=80, seed=4)
    with pytest.raises(ValueError, match="not evaluated on the same episodes"):
        compare(bayes, elsewhere)


def test_eval_json_output_parses_and_has_the_figures():
    res = CliRunner().invoke(
        _app(),
        [
            "eval",
            "--policy",
            "bayes",
            "--episodes",
            "30",
            "--walls",
            "1-2",
            "--moves",
            "8",
            "--intensity",
            "1e8:1e9",
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["env"]["moves"] == 8 and out["env"]["walls"] == [1, 2]
    assert out["env"]["intensity"] == {"kind": "uniform", "values": [1e8, 1e9]}
    for part in ("result", "oracle"):
        for key in ("success_rate", "success_ci", "time_mean", "time_ci", "cost_mean", "cost_ci"):
            assert key in out[part]
        assert out[part]["episodes"] == 30
    assert (
        out["oracle"]["time_mean"]
        == out["oracle"]["cost_mean"]
        == out["oracle"]["lower_bound_mean"]
    )
    ratio = out["result"]["time_mean"] / out["oracle"]["time_mean"]
    assert out["ratios"]["time_ratio"] == pytest.approx(ratio)


def test_eval_text_output():
    res = CliRunner().invoke(
        _app(), ["eval", "--policy", "uniform", "--episodes", "20", "--agents", "2"]
    )
    assert res.exit_code == 0, res.output
    assert "2 agents" in res.output and "oracle:" in res.output and "ratio to oracle" in res.output


@pytest.mark.parametrize(
    ("args", "flag"),
    [
        (["--grid", "ten"], "--grid"),
        (["--walls", "a-b"], "--walls"),
        (["--intensity", "1e9:1e8"], "--intensity"),
        (["--moves", "6"], "--moves"),
        (["--agents", "0"], "--agents"),
        (["--agents", "9", "--grid", "3x3"], "--agents"),
        (["--episodes", "0"], "--episodes"),
        (["--policy", "nonsense"], "--policy"),
    ],
)
def test_eval_bad_flags_name_the_flag(args, flag):
    if "--policy" not in args:
        args = ["--policy", "random", *args]
    res = CliRunner().invoke(_app(), ["eval", *args])
    assert res.exit_code == 2
    assert flag in res.output


def _save_random_model(path, kind: str, spec: EnvSpec):
    torch = pytest.importorskip("torch")
    pytest.importorskip("workers.mdrl.networks")
    from workers.mdrl.modelio import save_model
    from workers.mdrl.networks import ActorCritic
    from workers.mdrl.observations import ObservationSpec, make_observer
    from workers.mdrl.ppo import PPOConfig

    torch.manual_seed(0)
    obs = ObservationSpec(kind=kind)
    observer = make_observer(spec, obs)
    return save_model(
        path, ActorCritic.for_observer(observer, spec.num_actions), spec, obs, PPOConfig()
    )


def test_eval_model_directory_defaults_to_its_card_and_rejects_what_it_cannot_take(tmp_path):
    odmtl = _save_random_model(tmp_path / "odmtl", "odmtl", EnvSpec(agents=2))
    cmtl = _save_random_model(tmp_path / "cmtl", "cmtl", EnvSpec(agents=2))
    runner, app = CliRunner(), _app()
    res = runner.invoke(app, ["eval", "--policy", str(odmtl), "--episodes", "4", "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["env"]["agents"] == 2  # from the card
    # ODMTL windows do not depend on the grid or the team size (> 1): both are fine
    res = runner.invoke(
        app,
        [
            "eval",
            "--policy",
            str(odmtl),
            "--episodes",
            "10",
            "--agents",
            "3",
            "--grid",
            "12x12",
            "--json",
        ],
    )
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["env"]["rows"] == 12
    # ... nor on a grid no larger than the window (w = 3 on 3 x 4: off-grid cells are padded)
    res = runner.invoke(
        app, ["eval", "--policy", str(odmtl), "--episodes", "6", "--grid", "3x4", "--json"]
    )
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["env"]["rows"] == 3
    # the joint CMTL actor is tied to its team size; moves change every actor's output size
    res = runner.invoke(app, ["eval", "--policy", str(cmtl), "--episodes", "4", "--agents", "3"])
    assert res.exit_code == 2 and "--agents" in res.output
    res = runner.invoke(app, ["eval", "--policy", str(odmtl), "--episodes", "4", "--moves", "8"])
    assert res.exit_code == 2 and "--moves" in res.output


def test_eval_as_expert_reviews_a_model_on_a_team_it_was_not_trained_for(tmp_path):
    """`--as-expert`: the team takes the expert's first choice through the MEDC adapter, so a
    one-agent model can be reviewed on a three-agent task that plain eval refuses; the oracle
    as an expert is the oracle, episode for episode; a faulty expert shows as one."""
    one = _save_random_model(tmp_path / "one", "odmtl", EnvSpec(agents=1))
    cmtl = _save_random_model(tmp_path / "cmtl", "cmtl", EnvSpec(agents=2))
    runner, app = CliRunner(), _app()

    def run(*args):
        return runner.invoke(app, ["eval", "--episodes", "30", *args])

    assert run("--policy", str(one), "--agents", "3").exit_code == 2  # not its actor's input
    res = run("--policy", str(one), "--agents", "3", "--as-expert", "--json")
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout)
    assert out["env"]["agents"] == 3 and out["policy"] == f"{one} (as expert)"
    assert out["result"]["episodes"] == 30

    oracle = json.loads(run("--policy", "oracle", "--as-expert", "--walls", "0-2", "--json").stdout)
    assert oracle["result"]["time_mean"] == oracle["oracle"]["time_mean"]
    assert oracle["result"]["cost_mean"] == oracle["oracle"]["cost_mean"]
    assert oracle["suggested_review"] == 5  # the review it suggests, 0-5
    idle = json.loads(run("--policy", "biased:0", "--as-expert", "--walls", "0-2", "--json").stdout)
    assert idle["result"]["success_rate"] < 0.5 < idle["oracle"]["success_rate"]
    assert idle["suggested_review"] <= 1
    text = run("--policy", "biased:0", "--as-expert", "--walls", "0-2").stdout
    assert f"suggested review as this task's expert: {idle['suggested_review']}/5" in text
    assert "suggested_review" not in json.loads(run("--policy", "oracle", "--json").stdout)

    for args in (["--policy", "nonsense"], ["--policy", "malicious:nonsense"],
                 ["--policy", str(cmtl), "--agents", "3"]):  # a joint actor fixes its team
        res = run(*args, "--as-expert")
        assert res.exit_code == 2 and "--policy" in res.output, (args, res.output)


def test_the_paired_bootstrap_runs_in_chunks_with_the_same_draws(monkeypatch) -> None:
    """The bootstrap held (2000, n) indices at once (3.7 GB at 100k episodes); in chunks of
    rows it draws the same stream, so the intervals are the same, to the bit."""
    import numpy as np

    import workers.mdrl.evaluate as ev

    num = np.random.default_rng(1).random(3001)
    den = np.random.default_rng(2).random(3001) + 0.5
    whole = ev._ratio_ci(num, den, np.random.default_rng(7), 500)
    for chunk in (1, 3001 * 7, 10**6):
        monkeypatch.setattr(ev, "BOOTSTRAP_CHUNK", chunk)
        assert ev._ratio_ci(num, den, np.random.default_rng(7), 500) == whole
