"""The training curve a model card carries (``card["curve"]``): what a model hub shows.

One format for every card (worker-made outcomes, the zoo, ``drlaas train``), read from the
trainer's ``metrics.csv`` (one row per update; ``Trainer`` and ``GeneralistTrainer`` write the
columns used here, and a resumed run has already dropped the rows after its checkpoint, so the
file is the run that happened once):

    {"x": "env_steps", "updates": 81, "points": [
        {"step": 8192, "wall_s": 0.97, "success": 1.0, "time": 23.5, "cost": 54.9}, ...]}

``step`` = env steps so far, ``wall_s`` = training seconds so far, ``success`` = success rate,
``time`` = mean episode length (time steps) and ``cost`` = mean moving cost of the episodes
that finished in the update (``None`` when none did). At most :data:`MAX_CURVE_POINTS` points:
a longer run is cut into that many consecutive buckets of updates, each point the mean of its
bucket's measured values at the bucket's last step and time (the last point is the run's end).
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

MAX_CURVE_POINTS = 200
"""Points kept in a card (a 6-minute zoo run has ~80 updates, a long task thousands)."""
CURVE_KEY = "curve"
_VALUES = {"success": "success", "time": "episode_length", "cost": "episode_cost"}
"""Card key -> metrics.csv column."""


def _num(text: str | None) -> float | None:
    try:
        v = float(text) if text not in (None, "") else None
    except ValueError:
        return None
    return v if v is not None and math.isfinite(v) else None


def _rows(path: str | Path) -> Iterator[dict[str, Any]]:
    """The rows of a ``metrics.csv`` with a step, as curve points, in file order."""
    with Path(path).open(newline="") as f:
        for row in csv.DictReader(f):
            step = _num(row.get("global_step"))
            if step is None:
                continue
            point: dict[str, Any] = {"step": int(step), "wall_s": _num(row.get("wall_time"))}
            point.update({k: _num(row.get(col)) for k, col in _VALUES.items()})
            yield point


def read_metrics(path: str | Path) -> list[dict[str, float | None]]:
    """The rows of a ``metrics.csv`` as curve points (unordered steps are sorted; a step logged
    twice keeps its last row); rows without a step are skipped."""
    by_step = {p["step"]: p for p in _rows(path)}
    return [by_step[s] for s in sorted(by_step)]


def _ordered_count(path: str | Path) -> int | None:
    """How many rows with a step ``path`` holds when their steps only increase (every
    trainer's file: a resumed run drops the rows after its checkpoint), else None."""
    n, last = 0, None
    for point in _rows(path):
        if last is not None and point["step"] <= last:
            return None
        n, last = n + 1, point["step"]
    return n


def downsample(points: list[dict[str, Any]], limit: int = MAX_CURVE_POINTS) -> list[dict[str, Any]]:
    """At most ``limit`` points: consecutive buckets of near-equal size, each the mean of its
    measured values (None where none was) at the bucket's last step and wall time."""
    return _downsample_stream(points, len(points), limit)


def _rounded(point: dict[str, Any]) -> dict[str, Any]:
    """4 decimals (a card stays small; the curve is for reading, the CSV keeps full precision)."""
    return {k: v if v is None or k == "step" else round(v, 4) for k, v in point.items()}


def _downsample_stream(
    points: Iterable[dict[str, Any]], n: int, limit: int
) -> list[dict[str, Any]]:
    """:func:`downsample` of the ``n`` ``points``, read one at a time (bucket ``b`` ends at
    point ``(b + 1) * n // limit``), holding one bucket's sums, not every point."""
    if n <= limit:
        return [_rounded(p) for p in points]
    out: list[dict[str, Any]] = []
    sums = {key: [0, 0] for key in _VALUES}  # key -> [sum, count] of the measured values
    for i, p in enumerate(points):
        for key in _VALUES:
            if p.get(key) is not None:
                sums[key][0] += p[key]
                sums[key][1] += 1
        if i + 1 == (len(out) + 1) * n // limit:  # the last point of bucket len(out)
            point = {"step": p["step"], "wall_s": p.get("wall_s")}
            point.update({k: total / count if count else None
                          for k, (total, count) in sums.items()})
            out.append(_rounded(point))
            sums = {key: [0, 0] for key in _VALUES}
    return out


def training_curve(metrics_csv: str | Path, limit: int = MAX_CURVE_POINTS) -> dict[str, Any]:
    """The card's ``curve`` section from a run's ``metrics.csv``. Read twice, a row at a time,
    when its steps only increase: a long run of tiny updates (a spec may ask for one env step
    per update for a week) has millions of rows, and holding them all took more memory than
    the run itself, after all its training."""
    n = _ordered_count(metrics_csv)
    if n is None:  # out of order or logged twice: sorted in memory
        points = read_metrics(metrics_csv)
        return {"x": "env_steps", "updates": len(points), "points": downsample(points, limit)}
    return {"x": "env_steps", "updates": n,
            "points": _downsample_stream(_rows(metrics_csv), n, limit)}


def attach_curve(model_dir: str | Path, metrics_csv: str | Path) -> bool:
    """Write the curve of ``metrics_csv`` into the card (``model.json``) of ``model_dir``;
    False (card unchanged) when there is no metrics file."""
    from workers.mdrl.modelio import CARD

    metrics_csv, card_path = Path(metrics_csv), Path(model_dir) / CARD
    if not metrics_csv.is_file():
        return False
    card = json.loads(card_path.read_text())
    card[CURVE_KEY] = training_curve(metrics_csv)
    card_path.write_text(json.dumps(card, indent=1))
    return True
