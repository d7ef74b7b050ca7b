"""The worker's trial of an MEDC run's experts (workers/mdrl/review.py): each expert followed
by the team on the task, next to the oracle on the same episodes, the 0-5 review it suggests,
and the card section the model and task pages read."""

from __future__ import annotations

import json
import math
import time

import pytest

from workers.mdrl.evaluate import compare, evaluate
from workers.mdrl.experts import FollowExpert
from workers.mdrl.review import (
    TrialTimeout,
    attach_review,
    middle_review,
    review_experts,
    suggested_review,
)
from workers.mdrl.spec import EnvSpec


@pytest.mark.parametrize(("success", "ratio", "review"), [
    (1.0, 1.0, 5),      # the oracle's figures
    (1.0, 0.9, 5),      # faster than the oracle's mean on these episodes: capped at 5
    (1.0, 1.25, 4),     # 5 / 1.25
    (1.0, 1.43, 3),     # 3.497 -> 3
    (0.5, 1.0, 2),      # 2.5 -> 2: half the episodes lost halves the review
    (0.0, 1.0, 0),      # never finds the source
    (1.0, 10.0, 0),     # 0.5 -> 0: ten times the oracle's time
    (1.0, math.inf, 0), (1.0, math.nan, 0), (1.0, None, 0), (1.0, 0.0, 0), (1.0, -1.0, 0),
    (1.5, 1.0, 0), (-0.1, 1.0, 0),  # not a rate: no review to suggest
])
def test_the_suggested_review_scales_success_by_the_oracle_time(success, ratio, review):
    assert suggested_review(success, ratio) == review


def test_the_trial_measures_each_expert_on_the_same_episodes_as_the_oracle():
    """The oracle as an expert is the oracle (5/5); an idling expert fails (0/5); each row is
    the expert followed by the team (FollowExpert) on the review's episodes."""
    spec = EnvSpec(agents=2, rows=6, cols=6, walls=(0, 1))
    review = review_experts([("the oracle", "oracle"), ("idle", "biased:0"),
                             ("random", "random")], spec, episodes=40, seed=3)
    assert review["episodes"] == 40 and review["seed"] == 3
    oracle_row, idle, rand = review["experts"]
    assert [r["ref"] for r in review["experts"]] == ["the oracle", "idle", "random"]
    assert oracle_row["time"] == review["oracle_time"] and oracle_row["time_vs_oracle"] == 1.0
    assert oracle_row["success"] == 1.0 and oracle_row["suggested_review"] == 5
    assert idle["success"] < 0.5 and idle["suggested_review"] == 0
    assert rand["time"] > oracle_row["time"]
    follow = evaluate(FollowExpert("random", 3 + 2), spec, 40, seed=3)
    assert rand["time"] == follow.time_mean and rand["success"] == follow.success_rate
    ratio = compare(follow, evaluate(FollowExpert("oracle"), spec, 40, seed=3)).time_ratio
    assert rand["time_vs_oracle"] == pytest.approx(ratio)
    assert rand["suggested_review"] == suggested_review(follow.success_rate, ratio)
    json.dumps(review, allow_nan=False)  # a card section: strict JSON


def test_several_trials_suggest_their_middle_review():
    """One outlying worker does not set the review the task page starts at."""
    assert middle_review([]) is None
    assert middle_review([3]) == 3
    assert middle_review([5, 1, 4]) == 4
    assert middle_review([4, 2]) == 2  # the lower middle
    assert middle_review([0, 5, 5, 5]) == 5


def test_the_trial_stops_at_its_deadline_and_is_unchanged_before_it():
    """An idling expert on long episodes takes every step of the horizon: the trial raises
    TrialTimeout at its first step after the deadline instead of running on, and with time
    to spare it gives the same figures as without a deadline."""
    spec = EnvSpec(agents=2, rows=12, cols=12, max_steps=5000)
    with pytest.raises(TrialTimeout):  # unbounded, it runs 40 x 5,000 steps and returns
        review_experts([("idle", "biased:0")], spec, episodes=40, seed=3,
                       deadline=time.monotonic() + 0.05)
    small = EnvSpec(agents=2, rows=6, cols=6)
    experts = [("random", "random")]
    assert review_experts(experts, small, episodes=20, seed=3,
                          deadline=time.monotonic() + 600) == review_experts(
        experts, small, episodes=20, seed=3)


def test_the_trial_goes_into_the_card_of_an_expert_guided_model(tmp_path):
    guided, plain = tmp_path / "guided", tmp_path / "plain"
    for d, training in ((guided, {"experts": {"method": "DC (Alg. 4.1)", "experts": []}}),
                        (plain, {"env_steps": 10})):
        d.mkdir()
        (d / "model.json").write_text(json.dumps({"model": "ODMTL", "training": training}))
    review = {"episodes": 1, "experts": []}
    assert attach_review(guided, review)
    card = json.loads((guided / "model.json").read_text())
    assert card["training"]["experts"] == {"method": "DC (Alg. 4.1)", "experts": [],
                                           "review": review}
    assert not attach_review(plain, review)  # trained without experts: nothing to review
    assert json.loads((plain / "model.json").read_text())["training"] == {"env_steps": 10}
    assert not list(guided.glob("*.tmp"))
