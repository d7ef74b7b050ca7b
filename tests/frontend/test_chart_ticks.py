"""The curve chart's axis ticks, run in Node (the module the browser loads, unchanged): two
curve points one float step apart, which the card and progress schemas accept, made
``niceTicks`` loop for ever and froze the model and task pages (audit of 2026-12-03, F4)."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path

import pytest

CHART = Path(__file__).resolve().parents[2] / "frontend" / "js" / "chart.js"
NODE = shutil.which("node")


def ticks(ranges: list[tuple[float, float, int]]) -> list[list[float]]:
    script = (
        f"import {{ niceTicks }} from {json.dumps(CHART.as_uri())};\n"
        f"const ranges = {json.dumps(ranges)};\n"
        "console.log(JSON.stringify(ranges.map(([lo, hi, n]) => niceTicks(lo, hi, n))));\n"
    )
    done = subprocess.run([NODE or "node", "--input-type=module", "-e", script],
                          capture_output=True, text=True, timeout=20, check=True)
    return json.loads(done.stdout)


@pytest.mark.skipif(NODE is None, reason="node is not installed")
def test_ticks_end_and_cover_every_range() -> None:
    a = 123456.789
    ranges = [
        (a, math.nextafter(a, math.inf), 5),  # one ulp apart: looped for ever
        (1e300, math.nextafter(1e300, math.inf), 5),
        (123456789.123, math.nextafter(123456789.123, math.inf), 4),
        (0.0, 1.0, 5),
        (0.0, 1e6, 5),
        (-3.0, 7.0, 4),
        (5.0, 5.0, 5),
    ]
    out = ticks(ranges)
    assert out[3] == [0, 0.2, 0.4, 0.6, 0.8, 1]
    assert out[4] == [0, 200000, 400000, 600000, 800000, 1000000]
    for (lo, hi, n), got in zip(ranges, out, strict=True):
        assert 1 <= len(got) <= 4 * n + 2, (lo, hi, got)
        assert got == sorted(got)
        if hi > lo and hi - lo > abs(hi) * 1e-9:  # a real span: ticks inside it, a few
            assert all(lo - 1e-9 * abs(lo) <= t <= hi + 1e-9 * abs(hi) for t in got), got
            assert len(got) >= 2
