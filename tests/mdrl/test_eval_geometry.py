"""Evaluation on large grids: the env's static geometry is built once per geometry (cached,
read-only), chunks of episodes are stepped together for policies that allow it, and the
figures stay bit for bit what they were (digests computed with the code before the change);
confidence bounds stay within the support of time and cost."""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest

from workers.mdrl import env as env_mod
from workers.mdrl.baselines import make_baseline
from workers.mdrl.env import TargetLocalizationEnv
from workers.mdrl.evaluate import EvalReport, evaluate
from workers.mdrl.spec import EnvSpec


class ReadingsPolicy:
    """Deterministic env by env, and led by the readings (so by the reading-noise stream)."""

    name = "readings"

    def reset(self, env) -> None:
        pass

    def act(self, env) -> np.ndarray:
        mask = env.action_mask()
        B, N, A = mask.shape
        r = np.asarray(env.readings)[np.arange(B)[:, None], env.pos]
        key = (np.floor(r).astype(np.int64) * 7 + env.t[:, None] * 3 + np.arange(N)) % A
        order = (key[..., None] + np.arange(A)) % A
        ok = np.take_along_axis(mask, order, -1)
        return np.take_along_axis(order, ok.argmax(-1)[..., None], -1)[..., 0].astype(np.int64)


def _digest(rep: EvalReport) -> str:
    h = hashlib.sha256()
    for a in (rep.found, rep.time, rep.cost, rep.target, rep.lower_bound):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


# (spec, episodes, seed, batch) -> {policy: digest}, computed with the code before the
# geometry cache and the grouped chunks (b8f4499): the 40 x 40 specs' chunks hold 7 episodes
# (the B x C x C cap), which the oracle and the readings policy now step together.
CASES = [
    (EnvSpec(), 70, 3, None,
     {"random": "cabad30615fe00e7", "oracle": "9867a72aa24de651",
      "readings": "436e713ed197b718", "uniform": "e9a0972890f1a066",
      "bayes": "ad828cba2e2a956c"}),
    (EnvSpec(moves=8, walls=(1, 3)), 50, 5, 7,
     {"oracle": "f8cf4b7996969841", "readings": "f75d9bdbd036e8da", "bayes": "e2fd57a0cf9b1fb2"}),
    (EnvSpec(rows=40, cols=40, agents=2, walls=(2, 4), max_steps=30), 20, 6, None,
     {"random": "b3fe2404941ae4fe", "oracle": "27f77f4c2cab7b4b",
      "readings": "a74387d225b1c1b1"}),
    (EnvSpec(rows=40, cols=40, agents=3, max_steps=25), 23, 7, None,
     {"oracle": "96872bd98c1ed5ff", "readings": "fe797cb0eecd71c9"}),
]


@pytest.mark.parametrize("spec,episodes,seed,batch,expected", CASES)
def test_figures_bit_identical_to_before(spec, episodes, seed, batch, expected):
    for name, digest in expected.items():
        pol = ReadingsPolicy() if name == "readings" else make_baseline(name, seed=1)
        rep = evaluate(pol, spec, episodes, seed=seed, batch=batch)
        assert _digest(rep) == digest, name


def test_chunks_stepped_together(monkeypatch):
    """A large grid's 1-episode chunks run in one env for a model-like policy, one env per
    chunk for the baselines holding C x C tables; the same episodes either way."""
    built = []
    real = TargetLocalizationEnv.__init__

    def counting(self, spec, num_envs=1, *args, **kwargs):
        built.append(num_envs)
        real(self, spec, num_envs, *args, **kwargs)

    monkeypatch.setattr(TargetLocalizationEnv, "__init__", counting)
    spec = EnvSpec(rows=64, cols=64, agents=2, max_steps=5)
    grouped = evaluate(ReadingsPolicy(), spec, 12, seed=1)
    assert grouped.batch == 1 and built == [12]
    built.clear()
    one_by_one = evaluate(make_baseline("uniform"), spec, 3, seed=1)
    assert built == [1, 1, 1]
    assert np.array_equal(one_by_one.target, grouped.target[:3])


def test_geometry_built_once_per_geometry(monkeypatch):
    monkeypatch.setattr(env_mod, "_GEOMETRY", {})
    calls = []
    real = env_mod._build_geometry

    def counting(key):
        calls.append(key)
        return real(key)

    monkeypatch.setattr(env_mod, "_build_geometry", counting)
    spec = EnvSpec(rows=12, cols=12, agents=2, walls=(1, 2), max_steps=10)
    evaluate(make_baseline("uniform"), spec, 9, seed=0, batch=2)  # 5 chunks, 5 envs
    evaluate(make_baseline("oracle"), spec.replace(agents=3), 9, seed=0, batch=2)
    assert len(calls) == 1  # agents, walls, intensity: not geometry
    a = TargetLocalizationEnv(spec, 2, seed=0)
    b = TargetLocalizationEnv(spec, 3, seed=1)
    for name in ("_free_dist", "_free_gain", "_free_next", "centre_m", "_slant_x", "_slant_y"):
        assert getattr(a, name) is getattr(b, name)
        assert not getattr(a, name).flags.writeable, name
        with pytest.raises(ValueError):
            getattr(a, name)[0] = 0
    TargetLocalizationEnv(spec.replace(moves=8), 1, seed=0)
    TargetLocalizationEnv(spec.replace(area_m=(20.0, 20.0)), 1, seed=0)
    assert len(calls) == 3


def test_geometry_cache_bounded(monkeypatch):
    monkeypatch.setattr(env_mod, "_GEOMETRY", {})
    monkeypatch.setattr(env_mod, "GEOMETRY_CACHE_ENTRIES", 2)
    for rows in (4, 5, 6, 7):
        env_mod.geometry(EnvSpec(rows=rows, cols=4, agents=1))
    assert [k[0] for k in env_mod._GEOMETRY] == [6, 7]


def test_threads_asking_for_one_geometry_at_once_build_it_once(monkeypatch):
    """Envs are built from threads too (the gateway's expert checks): a geometry asked for by
    several at once is built once and shared, and its lazy tables (slant) are one object."""
    import threading
    import time

    monkeypatch.setattr(env_mod, "_GEOMETRY", {})
    calls = []
    real = env_mod._build_geometry

    def slow(key):  # a build long enough for every thread to arrive while it runs
        calls.append(key)
        time.sleep(0.2)
        return real(key)

    monkeypatch.setattr(env_mod, "_build_geometry", slow)
    spec = EnvSpec(rows=9, cols=9, agents=1)
    start = threading.Barrier(8)
    got = []

    def ask():
        start.wait()
        geo = env_mod.geometry(spec)
        got.append((geo, geo.slant()))

    threads = [threading.Thread(target=ask) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert len(got) == 8 and len(calls) == 1
    assert all(g is got[0][0] and s is got[0][1] for g, s in got)


def test_blocks_need_sizes_that_add_up():
    spec = EnvSpec(rows=4, cols=4, agents=1)
    with pytest.raises(ValueError):
        TargetLocalizationEnv(spec, 3, autoreset=False, blocks=[(1, 1), (2, 1)])
    with pytest.raises(ValueError):
        TargetLocalizationEnv(spec, 2, autoreset=True, blocks=[(1, 1), (2, 1)])


def _report(time, cost, found):
    n = len(time)
    return EvalReport("p", EnvSpec(), 0, n, np.asarray(found, bool), np.asarray(time, np.int64),
                      np.asarray(cost, np.int64), np.zeros(n, np.int64), np.ones(n, np.int64))


def test_intervals_within_support():
    # 3 successes of skewed lengths: the raw t interval reaches far below 1 step and 0 moves
    rep = _report([1, 1, 18, 100, 100], [0, 0, 9, 60, 60], [True, True, True, False, False])
    s = rep.summary
    assert s["time_success_ci"][0] == 1.0 and s["time_success_ci"][1] > s["time_mean_success"]
    assert s["cost_success_ci"][0] == 0.0 and s["cost_success_ci"][1] > s["cost_mean_success"]
    for key in ("time_ci", "time_success_ci"):
        assert s[key][0] >= 1.0
    for key in ("cost_ci", "cost_success_ci"):
        assert s[key][0] >= 0.0
    one = _report([5], [3], [True]).summary  # n = 1: no interval, NaN stays NaN
    assert all(math.isnan(x) for x in one["time_ci"] + one["cost_success_ci"])
