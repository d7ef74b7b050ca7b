"""Held-out pass 5 on the contracts (docs/chain.md, "Held-out pass of 2026-12-05, second").

What the fourth pass found and left open, closed here: the domain lists as paged views, a cap on
the descriptions the events carry, and a bound on the commitments an approved worker keeps.
Each test fails on the contracts before the change it names.
"""

from __future__ import annotations

import annotated_types
from eth_utils import keccak

from backend.chain.platform import OfferState
from backend.schemas.common import CID_LENGTH
from backend.schemas.models import ModelCreate

from .conftest import ACCEPT_WINDOW, DOMAIN
from .helpers import cid_for, reverts

REWARD = 10**15
DURATION = 4 * ACCEPT_WINDOW
OTHER = DOMAIN + 1
CAP = 4096  # MAX_DESCRIPTION_BYTES of both contracts
RING = 16  # TMC.MAX_LIVE_COMMITMENTS


def _page(handle, fn: str, domain: int, offset: int, count: int) -> tuple[list[int], int]:
    page, total = handle.call(fn, domain, offset, count)
    return list(page), total


def test_domain_lists_are_read_by_pages(p, actors) -> None:
    """domainTasks / domainModels return every task or model the domain ever had: past some
    thousands an eth_call runs out of gas. domainTasksPage / domainModelsPage return positions
    [offset, offset + count) and the total, as getWorkers pages workers: a short page at the
    end, an empty one for count 0 or an offset at or past the end. Before: no such views."""
    r, w = actors.requester, actors.workers[0]
    p.umc.add_requester(r)
    p.umc.add_worker(w, [DOMAIN, OTHER], 8, 32, 1)
    tasks = [
        p.tmc.add_task(r, domain=DOMAIN, num_workers=1, reward=REWARD, duration=DURATION)[0]
        for _ in range(5)
    ]
    p.tmc.add_task(r, domain=OTHER, num_workers=1, reward=REWARD, duration=DURATION)
    models = [p.mmc.add_model(w, cid_for(("page", i)), DOMAIN, [1, 2])[0] for i in range(3)]
    for handle, fn, ids in ((p.tmc, "domainTasksPage", tasks), (p.mmc, "domainModelsPage", models)):
        n = len(ids)
        assert _page(handle, fn, DOMAIN, 0, 2) == (ids[:2], n)
        assert _page(handle, fn, DOMAIN, 2, 2) == (ids[2:4], n)
        assert _page(handle, fn, DOMAIN, n - 1, 10) == (ids[-1:], n)  # count past the end
        assert _page(handle, fn, DOMAIN, 0, n + 100) == (ids, n)
        assert _page(handle, fn, DOMAIN, 1, 0) == ([], n)  # count 0
        assert _page(handle, fn, DOMAIN, n, 1) == ([], n)  # offset at the end
        assert _page(handle, fn, DOMAIN, 2**256 - 1, 2**256 - 1) == ([], n)  # past it, no overflow
        assert _page(handle, fn, 47, 0, 5) == ([], 0)  # an empty domain
    assert _page(p.tmc, "domainTasksPage", OTHER, 0, 5) == ([6], 1)
    # the whole-list views are kept (existing callers) and agree with the pages
    assert p.tmc.call("domainTasks", DOMAIN) == tasks
    assert p.mmc.call("domainModels", DOMAIN) == models


def _fixed_max_length(model, field: str) -> int:
    return next(
        m.max_length
        for m in model.model_fields[field].metadata
        if isinstance(m, annotated_types.MaxLen)
    )


def test_descriptions_are_capped_where_the_platform_never_reaches(p, actors) -> None:
    """TaskAdded and ModelAdded carried a description of any length (~750 KB fits a block): the
    chain now caps both at 4,096 bytes (TasksDescriptionTooLong / ModelsDescriptionTooLong,
    naming the length and the cap). The cap agrees with what the platform sends: a task's
    description is its spec's CID, a model's at most 1,024 characters (the gateway's
    ModelCreate), 4 bytes each in UTF-8 at most. Before: 4,097 bytes went through."""
    assert CID_LENGTH <= CAP
    assert 4 * _fixed_max_length(ModelCreate, "description") <= CAP
    r, w = actors.requester, actors.workers[0]
    p.umc.add_requester(r)
    p.umc.add_worker(w, [DOMAIN], 8, 32, 1)
    widest = "\U0001d11e" * 1024  # 1,024 characters of 4 UTF-8 bytes: the gateway's widest
    assert len(widest.encode()) == CAP

    def task(description: str):
        return p.tmc.add_task(
            r, domain=DOMAIN, num_workers=1, reward=REWARD, duration=DURATION,
            description=description,
        )

    _, rc = task(widest)
    assert rc.one("TaskAdded").args["description"] == widest
    err = reverts("TasksDescriptionTooLong", task, "x" * (CAP + 1))
    assert err.args_dict == {"length": CAP + 1, "maximum": CAP}
    reverts("TasksDescriptionTooLong", task, widest + "x")

    _, rc = p.mmc.add_model(w, cid_for("widest"), DOMAIN, [1, 2], widest)
    assert rc.one("ModelAdded").args["description"] == widest
    err = reverts(
        "ModelsDescriptionTooLong", p.mmc.add_model, w, cid_for("long"), DOMAIN, [1, 2],
        "y" * (CAP + 1),
    )
    assert err.args_dict == {"length": CAP + 1, "maximum": CAP}
    assert p.mmc.model_of_cid(cid_for("long")) == 0
    assert p.tmc.call("MAX_DESCRIPTION_BYTES") == CAP == p.mmc.call("MAX_DESCRIPTION_BYTES")


def _commit(p, worker: str, seed: object):
    h = keccak(text=repr(seed))
    return h, p.tmc.transact("commitCid", h, sender=worker)


def test_a_worker_keeps_its_last_sixteen_commitments(p, actors) -> None:
    """commitCid wrote one slot per new commitment for ever (approved workers only, but any
    number of them). Each worker now keeps its last 16 in a ring: its 17th evicts its first if
    that one is still unspent (CidCommitmentEvicted; cidCommits 0, so the gateway commits it
    again), and the other 16 stay. Before: the first stayed committed for ever."""
    w = actors.workers[0]
    p.umc.add_worker(w, [DOMAIN], 8, 32, 1)
    made = [_commit(p, w, ("ring", i)) for i in range(RING)]
    assert all(p.tmc.call("cidCommits", h) == rc.block_number for h, rc in made)
    assert not any(rc.named("CidCommitmentEvicted") for _, rc in made)
    h17, rc = _commit(p, w, ("ring", RING))
    first = made[0][0]
    assert [e.args["commitment"] for e in rc.named("CidCommitmentEvicted")] == [first]
    assert rc.one("CidCommitmentEvicted").args["worker"] == w
    assert p.tmc.call("cidCommits", first) == 0
    assert all(p.tmc.call("cidCommits", h) != 0 for h, _ in made[1:])
    assert p.tmc.call("cidCommits", h17) == rc.block_number
    assert not p.tmc.call("committedBefore", first)
    # committed again, it is live again (in a new position, with a new block)
    rc = p.tmc.transact("commitCid", first, sender=w)
    assert p.tmc.call("cidCommits", first) == rc.block_number
    assert p.tmc.call("MAX_LIVE_COMMITMENTS") == RING
    # and a repeat of a live commitment still keeps its block and evicts nothing
    block = p.tmc.call("cidCommits", h17)
    rc = p.tmc.transact("commitCid", h17, sender=w)
    assert rc.named("CidCommitted") == [] and rc.named("CidCommitmentEvicted") == []
    assert p.tmc.call("cidCommits", h17) == block


def test_the_honest_path_survives_the_ring(p, actors) -> None:
    """The daemon commits an outcome's CID, uploads, then reveals it: fifteen more
    commitments of the same worker in between still leave it revealable. A commitment spent by
    its reveal and made again later is not evicted by the ring position it first had, and a
    worker's evictions never drop a commitment another worker made first."""
    r, w, other = actors.requester, actors.workers[0], actors.workers[1]
    p.umc.add_requester(r)
    p.umc.add_worker(w, [DOMAIN], 8, 32, 1)
    p.umc.add_worker(other, [DOMAIN], 4, 16, 1)
    tid, _ = p.tmc.add_task(r, domain=DOMAIN, num_workers=1, reward=REWARD, duration=DURATION)
    assert p.tmc.allocate(r, tid)[0] == [w]
    p.tmc.transact("acceptOffer", tid, sender=w)
    cid = cid_for("outcome behind fifteen commitments")
    p.tmc.commit_cid(w, cid)  # ring position 0
    for i in range(RING - 1):
        _commit(p, w, ("between", i))
    rc = p.tmc.transact("submitOutcome", tid, cid, sender=w)
    assert rc.one("OutcomeSubmitted").args["cid"] == cid
    assert p.tmc.offer(tid, w)["state"] == OfferState.SUBMITTED

    # the other worker's live commitment, which w "commits" too (a no-op for w): none of w's
    # commitments below, which wrap w's ring three times, evicts it
    theirs, _ = _commit(p, other, "theirs")
    assert p.tmc.transact("commitCid", theirs, sender=w).named("CidCommitted") == []
    # a commitment of w spent and made again: the ring holds it twice
    again = keccak(text="made twice")
    p.tmc.transact("commitCid", again, sender=w)
    p.tmc.transact("commitCid", keccak(text="filler"), sender=w)
    for i in range(RING - 2):
        _commit(p, w, ("wrap", i))
    # `again` is now the oldest of w's ring: evicted by w's next commitment, not before
    assert p.tmc.call("cidCommits", again) != 0
    rc = _commit(p, w, "evicts again")[1]
    assert [e.args["commitment"] for e in rc.named("CidCommitmentEvicted")] == [again]
    assert p.tmc.call("cidCommits", theirs) != 0
    for i in range(2 * RING):
        _commit(p, w, ("more", i))
    assert p.tmc.call("cidCommits", theirs) != 0


def test_a_spent_commitment_made_again_is_not_evicted_by_its_old_position(p, actors) -> None:
    """A commitment spent by submitOutcome keeps its hash in its ring position; made again
    later it sits in a newer position, and overwriting the old one must leave it live."""
    r, w = actors.requester, actors.workers[0]
    p.umc.add_requester(r)
    p.umc.add_worker(w, [DOMAIN], 8, 32, 1)
    tid, _ = p.tmc.add_task(r, domain=DOMAIN, num_workers=1, reward=REWARD, duration=DURATION)
    assert p.tmc.allocate(r, tid)[0] == [w]
    p.tmc.transact("acceptOffer", tid, sender=w)
    cid = cid_for("spent then made again")
    p.tmc.submit_outcome(w, tid, cid)  # ring position 0, spent
    h = p.tmc.call("cidCommitment", cid, w)
    assert p.tmc.call("cidCommits", h) == 0
    for i in range(RING - 2):
        _commit(p, w, ("fill", i))  # positions 1..14
    rc = p.tmc.transact("commitCid", h, sender=w)  # position 15: live again
    assert rc.one("CidCommitted").args["commitment"] == h
    rc = _commit(p, w, "overwrites position 0")[1]  # position 0 held h (spent)
    assert rc.named("CidCommitmentEvicted") == []
    assert p.tmc.call("cidCommits", h) != 0
