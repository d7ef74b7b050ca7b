"""Anti-spam: the admin-set minimum reward per worker-hour on TMC.addTask."""

from __future__ import annotations

import pytest

from .conftest import DOMAIN
from .helpers import reverts

PER_HOUR = 7_200  # wei per worker-hour: 2 wei per second


@pytest.fixture
def tmc(p, actors):
    p.umc.add_requester(actors.requester)
    return p.tmc


def test_setter_is_admin_only_and_emits(tmc, actors) -> None:
    for who in (actors.requester, actors.workers[0], actors.outsider):
        err = reverts("TasksNotAdmin", tmc.set_min_reward_per_hour, who, PER_HOUR)
        assert err.args_dict == {"account": who}
    assert tmc.call("minRewardPerHour") == 0
    rc = tmc.set_min_reward_per_hour(actors.admin, PER_HOUR)
    assert rc.one("MinRewardPerHourUpdated").args["weiPerHour"] == PER_HOUR
    assert tmc.call("minRewardPerHour") == PER_HOUR
    reverts("TasksBadConfig", tmc.set_min_reward_per_hour, actors.admin, 2**96)


def test_reward_below_minimum_reverts_naming_both(tmc, actors) -> None:
    tmc.set_min_reward_per_hour(actors.admin, PER_HOUR)
    add = {"domain": DOMAIN, "num_workers": 3, "duration": 1_800}  # half an hour: 3,600 wei
    err = reverts("TasksRewardBelowMinimum", tmc.add_task, actors.requester, reward=3_599, **add)
    assert err.args_dict == {"reward": 3_599, "minimum": 3_600}
    reverts("TasksRewardBelowMinimum", tmc.add_task, actors.requester, reward=0, **add)
    tid, _ = tmc.add_task(actors.requester, reward=3_600, **add)
    assert tmc.task(tid)["reward"] == 3_600


def test_minimum_rounds_up_to_the_wei(tmc, actors) -> None:
    tmc.set_min_reward_per_hour(actors.admin, 1_000)
    assert tmc.min_reward(1) == 1  # 1000 / 3600 = 0.28 wei -> 1
    assert tmc.min_reward(3_600) == 1_000 and tmc.min_reward(3_601) == 1_001
    add = {"domain": DOMAIN, "num_workers": 1, "duration": 3_601}
    reverts("TasksRewardBelowMinimum", tmc.add_task, actors.requester, reward=1_000, **add)
    tmc.add_task(actors.requester, reward=1_001, **add)


def test_zero_minimum_leaves_a_one_wei_floor(tmc, actors) -> None:
    """No minimum set still refuses free tasks (issue 8, finding 2)."""
    tmc.set_min_reward_per_hour(actors.admin, PER_HOUR)
    tmc.set_min_reward_per_hour(actors.admin, 0)
    assert tmc.min_reward(86_400) == 1
    add = {"domain": DOMAIN, "num_workers": 1, "duration": 86_400}
    reverts("TasksRewardBelowMinimum", tmc.add_task, actors.requester, reward=0, **add)
    tmc.add_task(actors.requester, reward=1, **add)
