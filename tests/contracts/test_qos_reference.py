"""Tests of the pure-Python QoS reference (backend/chain/qos.py): fixed point vs float,
atan approximation bound, greedy top-NW vs a full sort, constraint filtering."""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from backend.chain import qos
from backend.chain.qos import (
    ATAN_MAX_ERR,
    HALF,
    ONE,
    QOS_MODEL_MAX_ERR,
    QOS_SHARING_MAX_ERR,
    QOS_TRAINING_MAX_ERR,
    REVIEW_MAX,
    Counters,
    Model,
    ModelRequest,
    SharingTask,
    TaskType,
    TrainingTask,
    Worker,
)

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# ------------------------------------------------------------------ strategies


@st.composite
def counters(draw, max_count: int = 50) -> Counters:
    assigned = draw(st.integers(0, max_count))
    accepted = draw(st.integers(0, assigned))
    completed = draw(st.integers(0, accepted))
    n_ratings = draw(st.integers(0, completed))
    rating_sum = draw(st.integers(0, n_ratings * REVIEW_MAX))
    return Counters(assigned, accepted, completed, rating_sum, n_ratings)


DOMAIN = 3


@st.composite
def workers(draw) -> Worker:
    return Worker(
        domains=frozenset(draw(st.sets(st.integers(0, 4), max_size=3)) | {DOMAIN}),
        cpu_cores=draw(st.integers(0, 128)),
        ram_gb=draw(st.integers(0, 256)),
        gpu_series=draw(st.integers(0, 4)),
        counters={
            (DOMAIN, TaskType.TRAINING): draw(counters()),
            (DOMAIN, TaskType.SHARING): draw(counters()),
        },
        available=draw(st.booleans()),
    )


def env(d: int):
    return st.tuples(*[st.integers(0, 20)] * d)


# ------------------------------------------------------------------ Eq. 20: atan


def test_atan_fixed_error_bound_dense_grid():
    """Max |atan_fixed - (2/pi) atan| over a dense grid of [0, 1] and a log grid up to 1e24."""
    xs = list(range(0, ONE + 1, 7)) + [int(10 ** (6 + 18 * i / 5000)) for i in range(5001)]
    xs += list(range(ONE, 40 * ONE, 997))
    worst = 0.0
    prev_x, prev_v = -1, -1
    for x in sorted(set(xs)):
        v = qos.atan_fixed(x)
        assert 0 <= v <= ONE
        assert v >= prev_v, f"atan_fixed not monotone between {prev_x} and {x}"
        prev_x, prev_v = x, v
        worst = max(worst, abs(v / ONE - 2 / math.pi * math.atan(x / ONE)))
    assert worst <= ATAN_MAX_ERR
    assert qos.atan_fixed(0) == 0
    assert qos.atan_fixed(2**128 - 1) == ONE


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, qos.MAX_W1))
def test_cc_fixed_matches_float(cores, w1):
    fixed = qos.computational_capability_fixed(cores, w1)
    assert abs(fixed / ONE - qos.computational_capability(cores, w1 / ONE)) <= ATAN_MAX_ERR


def test_atan_rejects_out_of_range():
    with pytest.raises(ValueError, match="x"):
        qos.atan_fixed(-1)
    with pytest.raises(ValueError, match="w1"):
        qos.computational_capability_fixed(4, 0)


# ------------------------------------------------------------------ Eq. 10-11, 16-19, rating


@SETTINGS
@given(counters(max_count=2**64 - 1))
def test_reputation_fixed_is_floor_of_exact(c):
    fixed = qos.reputation_fixed(c.assigned, c.accepted, c.completed)
    if c.assigned == 0:
        assert fixed == HALF
    elif c.accepted == 0:
        assert fixed == 0
    else:
        # floor(sqrt(E/A) * ONE) exactly, checked with integers only
        assert fixed * fixed * c.assigned <= c.completed * ONE * ONE
        assert (fixed + 1) ** 2 * c.assigned > c.completed * ONE * ONE
    assert abs(fixed / ONE - qos.reputation(c.assigned, c.accepted, c.completed)) < 1e-6 + 1e-12


@SETTINGS
@given(counters(max_count=10**9))
def test_cm_cp_rating_fixed_match_float(c):
    pairs = [
        (qos.commitment_fixed(c.assigned, c.accepted), qos.commitment(c.assigned, c.accepted)),
        (qos.completion_fixed(c.accepted, c.completed), qos.completion(c.accepted, c.completed)),
        (qos.rating_fixed(c.rating_sum, c.rating_count), qos.rating(c.rating_sum, c.rating_count)),
        (
            qos.mmc_reputation_fixed(c.rating_sum, c.rating_count),
            qos.mmc_reputation(c.rating_sum, c.rating_count),
        ),
    ]
    for fixed, flt in pairs:
        assert 0 <= fixed <= ONE
        # floor of the exact value; the float may sit a rounding error below an exact integer
        assert -1e-6 <= flt * ONE - fixed < 1 + 1e-6


@SETTINGS
@given(st.integers(0, 2**64 - 1), st.integers(0, 2**64 - 1))
def test_expertise_fixed_matches_float(a, b):
    n, n_max = min(a, b), max(a, b)
    fixed = qos.expertise_fixed(n, n_max)
    assert -1e-6 <= qos.expertise(n, n_max) * ONE - fixed < 1 + 1e-6


def test_new_users_start_at_half():
    assert qos.reputation_fixed(0, 0, 0) == HALF
    assert qos.rating_fixed(0, 0) == HALF
    assert qos.mmc_reputation_fixed(0, 0) == HALF
    assert qos.expertise_fixed(0, 0) == HALF
    # someone declined every offer: commitment 0 -> reputation 0
    assert qos.reputation_fixed(3, 0, 0) == 0
    # reviews of 5/5 give rating 1; 0/5 give 0
    assert qos.rating_fixed(10, 2) == ONE and qos.rating_fixed(0, 2) == 0


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: qos.reputation_fixed(2, 3, 1), "completed <= accepted <= assigned"),
        (lambda: qos.reputation_fixed(-1, 0, 0), "assigned"),
        (lambda: qos.rating_fixed(11, 2), "rating total"),
        (lambda: qos.expertise_fixed(5, 4), "n_max"),
        (lambda: qos.qos_training_fixed(ONE + 1, 0, 0, 0), "exp"),
        (lambda: qos.env_distance_fixed((1, 2), (1, 2), (ONE, 1)), "sum to ONE"),
        (lambda: qos.env_distance_fixed((1, 2), (1,), (ONE,)), "length mismatch"),
        (lambda: Counters(1, 2, 0), "completed <= accepted <= assigned"),
        (lambda: Worker(frozenset({1}), cpu_cores=-2, ram_gb=1, gpu_series=1), "cpu_cores"),
        (lambda: SharingTask(1, 1, (1, 2), env_weights=(ONE,)), "2 environment weights"),
    ],
)
def test_bad_inputs_raise_named_errors(call, match):
    with pytest.raises(ValueError, match=match):
        call()


# ------------------------------------------------------------------ Eq. 13 / 22 weights


@given(st.integers(1, qos.MAX_ENV_DIMS))
def test_default_weights_sum_to_one(d):
    w = qos.default_weights(d)
    assert len(w) == d and sum(w) == ONE and max(w) - min(w) < d


@SETTINGS
@given(st.integers(1, 6).flatmap(lambda d: st.tuples(env(d), env(d))))
def test_env_distance_fixed_is_exact(pair):
    a, b = pair
    w = qos.default_weights(len(a))
    fixed = qos.env_distance_fixed(a, b, w)
    assert fixed == sum(wi * abs(x - y) for wi, x, y in zip(w, a, b, strict=True))
    assert math.isclose(fixed / ONE, qos.env_distance(a, b, [x / ONE for x in w]), abs_tol=1e-9)
    assert qos.env_distance_fixed(a, a, w) == 0


# ------------------------------------------------------------------ Eq. 21, 23, 12 pipelines


@SETTINGS
@given(
    st.lists(workers(), min_size=1, max_size=25),
    st.integers(1, 10),
    st.integers(1, 10**7),
)
def test_training_qos_fixed_matches_float(pool, nw, w1):
    task = TrainingTask(DOMAIN, nw, accepted_gpu_series=frozenset({1, 2, 3}))
    eligible, fixed = qos.training_qos_all(pool, task, w1)
    flt = qos.training_qos_float(pool, task, w1 / ONE)
    for ok, q, f in zip(eligible, fixed, flt, strict=True):
        assert 0 <= q <= ONE
        assert abs(q / ONE - f) <= QOS_TRAINING_MAX_ERR
        if not ok:
            assert q == 0


@SETTINGS
@given(st.lists(workers(), min_size=1, max_size=8), st.data())
def test_sharing_qos_fixed_matches_float(pool, data):
    d = data.draw(st.integers(1, 4))
    models = data.draw(
        st.lists(
            st.builds(
                Model,
                owner=st.integers(0, len(pool) - 1),
                domain=st.sampled_from([DOMAIN, DOMAIN + 1]),
                env=env(d),
            ),
            min_size=1,
            max_size=20,
        )
    )
    task = SharingTask(DOMAIN, data.draw(st.integers(1, 5)), data.draw(env(d)))
    eligible, fixed = qos.sharing_qos_all(models, pool, task)
    flt = qos.sharing_qos_float(models, pool, task)
    for ok, q, f in zip(eligible, fixed, flt, strict=True):
        assert abs(q / ONE - f) <= QOS_SHARING_MAX_ERR
        if not ok:
            assert q == 0


@st.composite
def mmc_models(draw, d: int) -> Model:
    n = draw(st.integers(0, 30))
    return Model(
        owner=draw(st.integers(0, 5)),
        domain=draw(st.sampled_from([DOMAIN, DOMAIN + 1])),
        env=draw(env(d)),
        alloc_count=n,
        total_review=draw(st.integers(0, n * REVIEW_MAX)),
    )


@SETTINGS
@given(st.integers(1, 4).flatmap(lambda d: st.tuples(st.lists(mmc_models(d), max_size=20), env(d))))
def test_model_qos_fixed_matches_float(case):
    models, req_env = case
    req = ModelRequest(DOMAIN, 3, req_env, min_model_reputation=200_000)
    eligible, fixed = qos.model_qos_all(models, req)
    flt = qos.model_qos_float(models, req)
    for m, ok, q, f in zip(models, eligible, fixed, flt, strict=True):
        assert abs(q / ONE - f) <= QOS_MODEL_MAX_ERR
        assert ok == (
            m.domain == DOMAIN
            and qos.mmc_reputation_fixed(m.total_review, m.alloc_count) >= 200_000
        )


def test_closest_environment_model_wins():
    """Thesis Fig. 7.8: for a 3-agent 3-wall request, the 2A2W expert beats 1A2W and 1A0W."""
    pool = [Worker(frozenset({DOMAIN}), 8, 16, 1) for _ in range(3)]
    models = [Model(i, DOMAIN, e) for i, e in enumerate([(1, 0), (1, 2), (2, 2)])]
    task = SharingTask(DOMAIN, 3, (3, 3))
    assert qos.recruit_sharing(models, pool, task) == [2, 1, 0]
    assert qos.allocate_models(models, ModelRequest(DOMAIN, 1, (3, 3))) == [2]


def test_expertise_normalised_over_eligible_candidates():
    """Eq. 16: N_max comes from the workers that pass the constraints, not the whole pool."""
    hist = {(DOMAIN, TaskType.TRAINING): Counters(10, 10, 10, 50, 10)}
    veteran_no_gpu = Worker(
        frozenset({DOMAIN}), 64, 64, 0, {(DOMAIN, TaskType.TRAINING): Counters(40, 40, 40)}
    )
    a = Worker(frozenset({DOMAIN}), 8, 16, 1, hist)
    task = TrainingTask(DOMAIN, 2, accepted_gpu_series=frozenset({1}))
    eligible, q = qos.training_qos_all([veteran_no_gpu, a], task)
    assert eligible == [False, True]
    # Exp = 1, Rep = 1, R = 1 -> QoS = CC
    assert q[1] == qos.computational_capability_fixed(8)


# ------------------------------------------------------------------ greedy top-NW


def full_sort_top(scores, k, eligible=None, exclude=frozenset()):
    idx = [i for i in range(len(scores)) if (eligible is None or eligible[i]) and i not in exclude]
    return sorted(idx, key=lambda i: (-scores[i], i))[:k]


@SETTINGS
@given(
    st.lists(st.integers(0, 5), max_size=60),  # small range: many ties
    st.integers(0, 12),
    st.data(),
)
def test_greedy_equals_full_sort_with_ties(scores, k, data):
    eligible = data.draw(st.lists(st.booleans(), min_size=len(scores), max_size=len(scores)))
    exclude = data.draw(st.sets(st.integers(0, max(len(scores) - 1, 0)), max_size=5))
    assert qos.greedy_top(scores, k, eligible, exclude) == full_sort_top(
        scores, k, eligible, exclude
    )


@SETTINGS
@given(st.lists(st.floats(0, 1), max_size=80), st.integers(0, 12))
def test_greedy_equals_full_sort_floats(scores, k):
    assert qos.greedy_top(scores, k) == full_sort_top(scores, k)


def test_greedy_tie_goes_to_earlier_registration():
    assert qos.greedy_top([7, 9, 7, 9, 7], 3) == [1, 3, 0]
    # next best after the offer to worker 1 expired
    assert qos.greedy_top([7, 9, 7, 9, 7], 1, exclude={1}) == [3]


@SETTINGS
@given(st.lists(workers(), min_size=1, max_size=30), st.integers(1, 10))
def test_recruit_training_is_top_nw_of_eligible(pool, nw):
    task = TrainingTask(DOMAIN, nw, min_cpu_cores=4, accepted_gpu_series=frozenset({1, 2}))
    eligible, q = qos.training_qos_all(pool, task)
    chosen = qos.recruit_training(pool, task)
    assert chosen == full_sort_top(q, nw, eligible)
    assert all(qos.training_eligible(pool[i], task) for i in chosen)
    assert len(chosen) == min(nw, sum(eligible))


# ------------------------------------------------------------------ constraints (7.5.1, 7.5.2)

GOOD = Counters(assigned=10, accepted=9, completed=8, rating_sum=16, rating_count=4)  # R = 0.8


def base_worker(**kw) -> Worker:
    args = dict(
        domains=frozenset({DOMAIN, 7}),
        cpu_cores=16,
        ram_gb=32,
        gpu_series=2,
        counters={(DOMAIN, TaskType.TRAINING): GOOD, (DOMAIN, TaskType.SHARING): GOOD},
    )
    args.update(kw)
    return Worker(**args)


REP_GOOD = qos.reputation_fixed(10, 9, 8)  # floor(sqrt(0.8) * ONE)
TASK = TrainingTask(
    DOMAIN,
    1,
    min_reputation=REP_GOOD,
    min_rating=800_000,
    min_cpu_cores=16,
    min_ram_gb=32,
    accepted_gpu_series=frozenset({1, 2}),
)


def test_constraints_pass_at_their_bounds():
    assert qos.training_eligible(base_worker(), TASK)


@pytest.mark.parametrize(
    "worker",
    [
        base_worker(domains=frozenset({7})),
        base_worker(cpu_cores=15),
        base_worker(ram_gb=31),
        base_worker(gpu_series=3),
        base_worker(gpu_series=0),
        base_worker(available=False),
        base_worker(counters={(DOMAIN, TaskType.TRAINING): Counters(10, 9, 7, 16, 4)}),  # rep
        base_worker(counters={(DOMAIN, TaskType.TRAINING): Counters(10, 9, 8, 15, 4)}),  # rating
        # history in another domain or task type does not count
        base_worker(counters={(7, TaskType.TRAINING): GOOD, (DOMAIN, TaskType.SHARING): GOOD}),
    ],
    ids=["domain", "cpu", "ram", "gpu", "no-gpu", "unavailable", "rep", "rating", "other-history"],
)
def test_each_training_constraint_filters(worker):
    assert not qos.training_eligible(worker, TASK)
    assert qos.recruit_training([worker], TASK) == []


def test_sharing_constraints():
    task = SharingTask(DOMAIN, 1, (3, 3), min_reputation=REP_GOOD, min_rating=800_000)
    pool = [
        base_worker(),
        base_worker(domains=frozenset({7})),
        base_worker(available=False),
        base_worker(counters={(DOMAIN, TaskType.SHARING): Counters(10, 9, 8, 15, 4)}),
        base_worker(counters={(DOMAIN, TaskType.TRAINING): GOOD}),  # no sharing history: 0.5
    ]
    models = [Model(i, DOMAIN, (3, 3)) for i in range(len(pool))]
    models += [Model(0, DOMAIN + 1, (3, 3)), Model(0, DOMAIN, (3, 3, 1))]
    ok = [qos.sharing_eligible(m, pool, task) for m in models]
    assert ok == [True, False, False, False, False, False, False]
    with pytest.raises(ValueError, match="owner 9"):
        qos.sharing_eligible(Model(9, DOMAIN, (3, 3)), pool, task)


def test_model_request_owner_reputation_filter():
    # owner 0 has one badly reviewed model, so its second (unreviewed) model is filtered too
    models = [Model(0, DOMAIN, (1,), 2, 1), Model(0, DOMAIN, (1,)), Model(1, DOMAIN, (5,))]
    req = ModelRequest(DOMAIN, 3, (1,), min_owner_reputation=HALF)
    eligible, _ = qos.model_qos_all(models, req)
    assert eligible == [False, False, True]


# ------------------------------------------------------------------ benchmark metaheuristics


def test_metaheuristics_return_valid_groups_no_better_than_greedy():
    """GA/PSO/ACO of benchmarks/recruitment return k distinct workers and never beat greedy,
    and on a tiny pool (12 workers, k = 2) each actually optimises: it finds the optimum."""
    import numpy as np

    from benchmarks.recruitment import metaheuristics as mh

    rng = np.random.default_rng(0)
    small = rng.random(12)
    optimum = np.sort(small)[-2:].mean()
    for solve in (mh.ga_select, mh.pso_select, mh.aco_select):
        idx = solve(small, 2, np.random.default_rng(1))
        assert mh.group_qos(small, idx) == pytest.approx(optimum)
    big = rng.random(200)
    for k in (1, 5):
        best = big[qos.greedy_top(list(big), k)].mean()
        for solve in (mh.ga_select, mh.pso_select, mh.aco_select):
            idx = solve(big, k, np.random.default_rng(2))
            assert len(set(idx.tolist())) == k and idx.min() >= 0 and idx.max() < big.size
            assert mh.group_qos(big, idx) <= best + 1e-12
    with pytest.raises(ValueError, match="group size k"):
        mh.ga_select(small, 13, rng)
