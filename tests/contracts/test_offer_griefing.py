"""Issue 8, finding 2: no offer the worker cannot accept and complete, and no free tasks.

An offer counted as assigned (A of Eq. 17) the moment it was made, so an offer made too close
to the deadline (or past it, once the acceptance window is counted) lowered the worker's
reputation with nothing it could do about it; with zero-reward tasks the attack was free.
Offers now count only once accepted or at their task's end (docs/chain.md, "Offers that
count"); the timing rule stays: every offer made can still be accepted and worked on."""

from __future__ import annotations

import pytest

from backend.chain import qos

from .conftest import ACCEPT_WINDOW, DOMAIN
from .helpers import CID, reverts

REWARD = 10**15
MIN_WORK = 60  # TasksManager.DEFAULT_MIN_WORK_TIME
SHORTEST = ACCEPT_WINDOW + MIN_WORK
MARGIN = 30  # seconds between blocks, so no assertion rests on an exact block time


@pytest.fixture
def setup(p, actors):
    p.umc.add_requester(actors.requester)
    w = actors.workers[0]
    p.umc.add_worker(w, [DOMAIN], 8, 32, 1)
    return p, actors.requester, w


def _reputation(p, w) -> int:
    c = p.umc.counters(w, DOMAIN, 0)
    return qos.reputation_fixed(c["assigned"], c["accepted"], c["completed"])


def test_defaults_are_readable(setup) -> None:
    p, _, _ = setup
    assert p.tmc.call("minWorkTime") == MIN_WORK == p.tmc.call("DEFAULT_MIN_WORK_TIME")
    assert p.tmc.duration_bounds() == (SHORTEST, 30 * 86_400)


def test_a_task_shorter_than_accept_plus_work_is_refused(setup) -> None:
    """The attack: a task whose deadline ends before the worker could accept and train."""
    p, r, w = setup
    for duration in (1, ACCEPT_WINDOW, SHORTEST - 1):
        err = reverts(
            "TasksBadDuration",
            p.tmc.add_task,
            r,
            domain=DOMAIN,
            num_workers=1,
            reward=REWARD,
            duration=duration,
        )
        assert err.args_dict == {"duration": duration, "minimum": SHORTEST, "maximum": 30 * 86_400}
    assert p.umc.counters(w, DOMAIN, 0)["assigned"] == 0
    assert _reputation(p, w) == qos.HALF


def test_no_offer_once_the_deadline_leaves_no_time_to_work(setup) -> None:
    p, r, w = setup
    duration = SHORTEST + 1_000
    tid, _ = p.tmc.add_task(r, domain=DOMAIN, num_workers=1, reward=REWARD, duration=duration)
    deadline = p.tmc.task(tid)["deadline"]
    p.chain.advance_time(1_000 + MARGIN)  # now + accept window + min work > deadline
    err = reverts("TasksTooLateToOffer", p.tmc.allocate, r, tid)
    assert err.args_dict == {"taskId": tid, "deadline": deadline}
    assert p.umc.counters(w, DOMAIN, 0)["assigned"] == 0
    assert _reputation(p, w) == qos.HALF


def test_an_offer_made_in_time_can_be_accepted_late_and_completed(setup) -> None:
    """The last allocation allowed still leaves the worker its whole window plus MIN_WORK."""
    p, r, w = setup
    duration = SHORTEST + MARGIN  # blocks may be a few seconds apart
    tid, _ = p.tmc.add_task(r, domain=DOMAIN, num_workers=1, reward=REWARD, duration=duration)
    offered, _ = p.tmc.allocate(r, tid)
    assert offered == [w]
    expiry = p.tmc.offer(tid, w)["expiry"]
    assert p.tmc.task(tid)["deadline"] - expiry >= MIN_WORK
    p.chain.advance_time(ACCEPT_WINDOW - MARGIN)  # near the end of the window
    p.tmc.transact("acceptOffer", tid, sender=w)
    p.tmc.submit_outcome(w, tid, CID)
    p.tmc.transact("reviewOutcome", tid, w, 5, True, sender=r)
    c = p.umc.counters(w, DOMAIN, 0)
    assert (c["assigned"], c["accepted"], c["completed"]) == (1, 1, 1)


def test_task_limits_are_an_admin_setting(setup, actors) -> None:
    p, r, _ = setup
    for who in (r, actors.workers[0], actors.outsider):
        err = reverts("TasksNotAdmin", p.tmc.set_task_limits, who, 3_600, 86_400)
        assert err.args_dict == {"account": who}
    rc = p.tmc.set_task_limits(actors.admin, 3_600, 7 * 86_400)
    assert rc.one("TaskLimitsUpdated").args == {"minWorkTime": 3_600, "maxDuration": 7 * 86_400}
    assert p.tmc.duration_bounds() == (ACCEPT_WINDOW + 3_600, 7 * 86_400)
    bad = ((0, 86_400), (3_600, 2**32), (3_600, ACCEPT_WINDOW + 3_599))
    for min_work, max_duration in bad:
        reverts("TasksBadConfig", p.tmc.set_task_limits, actors.admin, min_work, max_duration)
    # a longer acceptance window must still leave min work time within the longest task
    reverts("TasksBadConfig", p.tmc.transact, "setConfig", 1, 7 * 86_400, 60, sender=actors.admin)
    # a task posted before the limits rose is not offered once it is too short for them
    p.tmc.set_task_limits(actors.admin, MIN_WORK, 7 * 86_400)
    tid, _ = p.tmc.add_task(r, domain=DOMAIN, num_workers=1, reward=REWARD, duration=SHORTEST)
    p.tmc.set_task_limits(actors.admin, 3_600, 7 * 86_400)
    reverts("TasksTooLateToOffer", p.tmc.allocate, r, tid)


def test_zero_reward_is_refused_even_without_a_minimum(setup, actors) -> None:
    p, r, _ = setup
    assert p.tmc.call("minRewardPerHour") == 0
    assert p.tmc.min_reward(86_400) == 1
    err = reverts(
        "TasksRewardBelowMinimum",
        p.tmc.add_task,
        r,
        domain=DOMAIN,
        num_workers=2,
        reward=0,
        duration=86_400,
    )
    assert err.args_dict == {"reward": 0, "minimum": 1}
    p.tmc.add_task(r, domain=DOMAIN, num_workers=2, reward=1, duration=86_400)
