"""Held-out attack pass 4 on the contracts (docs/chain.md, "Held-out pass of 2026-12-05").

An attacker signing its own transactions (an outsider, a registered worker, a model owner, a
requester) went through the three contracts again, looking past what the earlier passes
recorded: role checks, griefing, escrow, loops and storage, Eq. 10-13 and 22-23, events,
integer and timing edges. Each test below fails on the contracts before the fix it names.
"""

from __future__ import annotations

import pytest

from backend.chain import errors
from backend.chain.platform import TaskStatus, Verdict

from .conftest import ACCEPT_WINDOW, DOMAIN
from .helpers import cid_for, reverts

REWARD = 10**15
DURATION = 4 * ACCEPT_WINDOW
OTHER = DOMAIN + 1


def _refused(name: str, fn, *args, **kwargs) -> errors.ContractError:
    """Like :func:`reverts`, for an error the contracts before the fix do not declare: the
    call must revert with a custom error of that name (before the fix it went through)."""
    with pytest.raises(errors.ContractError) as info:
        fn(*args, **kwargs)
    assert info.value.name == name, info.value
    return info.value


@pytest.fixture
def accepted_outcome(p, actors):
    """A worker covering DOMAIN and OTHER whose outcome of a DOMAIN task its requester
    accepted 5/5: (platform, worker, cid, task id)."""
    r, w = actors.requester, actors.workers[0]
    p.umc.add_requester(r)
    p.umc.add_worker(w, [DOMAIN, OTHER], 8, 32, 1)
    tid, _ = p.tmc.add_task(r, domain=DOMAIN, num_workers=1, reward=REWARD, duration=DURATION)
    assert p.tmc.allocate(r, tid)[0] == [w]
    p.tmc.transact("acceptOffer", tid, sender=w)
    cid = cid_for("outcome of a domain-3 task")
    p.tmc.submit_outcome(w, tid, cid)
    p.tmc.transact("reviewOutcome", tid, w, 5, True, sender=r)
    assert p.tmc.outcome_of(cid) == (w, tid, Verdict.ACCEPTED)
    return p, w, cid, tid


def test_an_outcome_is_listed_in_its_task_domain_only(accepted_outcome, actors) -> None:
    """The MMC lets a task's worker list its accepted outcome (provenance, thesis 7.7), and the
    gateway shows the listing as produced by that task (outcomeOf: "source: chain", the
    requester's 5/5). The listing's domain was the lister's choice: a worker covering two
    domains listed an outcome of a domain-3 task as a domain-4 model, ranked for domain-4
    requesters with the domain-3 requester's acceptance as its credential. Before the fix the
    listing went through; now ModelsOutcomeDomainMismatch(taskId, taskDomain, domain), and the
    same outcome lists in its task's domain."""
    p, w, cid, tid = accepted_outcome
    err = _refused("ModelsOutcomeDomainMismatch", p.mmc.add_model, w, cid, OTHER, [1, 2])
    assert err.args_dict == {"taskId": tid, "taskDomain": DOMAIN, "domain": OTHER}
    assert p.mmc.model_of_cid(cid) == 0
    mid, rc = p.mmc.add_model(w, cid, DOMAIN, [1, 2])
    assert rc.one("ModelAdded").args["domain"] == DOMAIN
    assert p.mmc.call("domainModels", OTHER) == []
    assert p.mmc.call("domainModels", DOMAIN) == [mid]
    # an own upload (no outcome) still lists in any domain its owner covers
    p.mmc.add_model(w, cid_for("own upload"), OTHER, [1, 2])
    # and the close of the task changes nothing of it
    assert p.tmc.task(tid)["status"] == TaskStatus.COMPLETED
    reverts("ModelsDuplicateModel", p.mmc.add_model, w, cid, DOMAIN, [1, 2])
