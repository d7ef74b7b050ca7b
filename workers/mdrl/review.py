"""Evidence for a requester's review of the experts an MEDC run used (MMC ``updateModelRep``,
Eq. 10-11): each expert followed by the team on the task's own environment, next to the
oracle on the same seeded episodes, and a 0-5 review suggested from it.

Before, the requester rated each allocated expert 0-5 with nothing to go on but the card's
usage counts. The worker already holds the verified experts when the run ends, so it
measures them there. The figures go into the outcome's card (``training.experts.review``),
and the model and task pages show them next to the review control. The suggestion is a
number the requester may take or overrule; the chain only sees the review actually sent.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

from workers.mdrl.baselines import OraclePolicy
from workers.mdrl.evaluate import compare, evaluate
from workers.mdrl.experts import FollowExpert
from workers.mdrl.modelio import CARD

REVIEW_EPISODES = 100
"""Episodes per expert of the review a worker appends to an expert-guided outcome's card."""

REVIEW_SEED = 20_261_204
"""Seed of the review episodes: apart from a run's evaluation episodes (``RunConfig.eval_seed``)
and the benchmarks' held-out ones, so an expert is not judged on what the run selected on."""

MAX_REVIEW = 5
"""The top of MMC's review scale (``updateModelRep`` takes 0-5)."""


def suggested_review(success_rate: float, time_vs_oracle: float | None) -> int:
    """A 0-5 review from what the team did following an expert: ``5 x success rate x oracle
    time / its time``, rounded. The oracle itself earns 5; a team that never finds the
    source, or an expert that idles it to the horizon, earns 0. Mean time already charges a
    failed episode the whole horizon, so the success factor only sharpens the penalty."""
    if not (0.0 <= success_rate <= 1.0) or time_vs_oracle is None \
            or not math.isfinite(time_vs_oracle) or time_vs_oracle <= 0:
        return 0
    return int(round(MAX_REVIEW * success_rate * min(1.0, 1.0 / time_vs_oracle)))


def middle_review(suggestions: list[int]) -> int | None:
    """The review several workers' trials suggest together: their middle one (the lower
    middle for an even count), so one outlying trial does not set it; None without any."""
    ordered = sorted(suggestions)
    return ordered[(len(ordered) - 1) // 2] if ordered else None


class TrialTimeout(Exception):
    """The trial was not done by its deadline."""


class Until:
    """``policy`` that raises :class:`TrialTimeout` at its first step after ``deadline``
    (``time.monotonic()``): 100 episodes of up to 10,000 steps per expert can take hours,
    and a worker's trial must not make its outcome late. Checked once per batched step."""

    def __init__(self, policy: Any, deadline: float) -> None:
        self.policy, self.deadline = policy, deadline

    def __getattr__(self, name: str) -> Any:  # rows_independent, name, ...
        return getattr(self.policy, name)

    def reset(self, env: Any) -> None:
        self.policy.reset(env)

    def act(self, env: Any) -> Any:
        if time.monotonic() > self.deadline:
            raise TrialTimeout("not done by its deadline")
        return self.policy.act(env)


def review_experts(experts: list[tuple[str, str]], env_spec: Any,
                   episodes: int = REVIEW_EPISODES, seed: int = REVIEW_SEED,
                   deadline: float | None = None) -> dict[str, Any]:
    """Each of ``experts`` ((name shown, ref ``load_expert`` takes: a model directory or a
    built-in)) followed by the team of ``env_spec`` on ``episodes`` seeded episodes, with the
    oracle on the same episodes; JSON-able, the card's ``training.experts.review``. Past
    ``deadline`` (``time.monotonic()``), :class:`TrialTimeout`."""
    def bounded(policy: Any) -> Any:
        return policy if deadline is None else Until(policy, deadline)

    oracle = evaluate(bounded(OraclePolicy()), env_spec, episodes, seed=seed, name="oracle")
    rows = []
    for i, (name, ref) in enumerate(experts):
        report = evaluate(bounded(FollowExpert(ref, seed + i, name=name)), env_spec, episodes,
                          seed=seed, name=name)
        ratio = compare(report, oracle).time_ratio
        s = report.to_dict()
        rows.append({
            "ref": name,
            "success": s["success_rate"],
            "time": s["time_mean"],
            "time_ci": s["time_ci"],
            "cost": s["cost_mean"],
            "time_vs_oracle": ratio if math.isfinite(ratio) else None,
            "suggested_review": suggested_review(report.success_rate, ratio),
        })
    return {"episodes": episodes, "seed": seed, "oracle_time": oracle.time_mean,
            "rule": f"round({MAX_REVIEW} x success x oracle time / time)", "experts": rows}


def attach_review(model_dir: str | Path, review: dict[str, Any]) -> bool:
    """Write ``review`` into the card (``model.json``) of ``model_dir`` under
    ``training.experts.review``; False (card unchanged) when the card names no experts."""
    path = Path(model_dir) / CARD
    card = json.loads(path.read_text())
    experts = card.get("training", {}).get("experts")
    if not isinstance(experts, dict):
        return False
    experts["review"] = review
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(card, indent=1))
    tmp.replace(path)
    return True
