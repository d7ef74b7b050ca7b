"""Commit-reveal of CIDs on the EVM (issue 8, finding 7): a CID is public from the moment its
transaction is pending; whoever sees it there and races it into the same block (commitment
and reveal) is refused, because a reveal needs a commitment of its own sender mined in an
earlier block. The race is played for real: automining off, the copier's two transactions
queued ahead of the producer's reveal (a higher tip), one block mined, on anvil (eth-tester
takes no second pending transaction of one sender)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from backend.chain.client import Chain, ContractHandle
from backend.chain.platform import Platform, Verdict, cid_commitment

from .conftest import ACCEPT_WINDOW, DOMAIN, Actors, actors_of, make_platform
from .helpers import CID, reverts
from .helpers import two_accepted as two_accepted_offers

REWARD = 10**15


@pytest.fixture
def two_accepted(p: Platform, actors: Actors) -> tuple[int, list[str]]:
    """One task, two workers who accepted it."""
    return two_accepted_offers(p, actors, DOMAIN, 2 * ACCEPT_WINDOW, REWARD)


class OneBlock:
    """Queue signed transactions on an anvil node with automining off (from the first
    :meth:`send`), then mine them as one block and automine again. Gas is fixed (nothing is
    estimated against the unmined state); a higher tip puts a transaction earlier in the
    block, as a front-runner would pay."""

    def __init__(self, p: Platform) -> None:
        self.chain = p.chain
        self.nonces: dict[str, int] = {}
        self.hashes: list[Any] = []

    def send(self, handle: ContractHandle, fn: str, *args: Any, sender: str, tip: int) -> int:
        w3 = self.chain.w3
        if not self.hashes:
            w3.provider.make_request("evm_setAutomine", [False])
        nonce = self.nonces.setdefault(sender, w3.eth.get_transaction_count(sender))
        self.nonces[sender] += 1
        tx = handle.contract.functions[fn](*args).build_transaction({
            "from": sender, "nonce": nonce, "gas": 1_000_000, "chainId": self.chain.chain_id,
            "maxFeePerGas": tip, "maxPriorityFeePerGas": tip,
        })
        signed = self.chain._keys[sender].sign_transaction(tx)
        self.hashes.append(w3.eth.send_raw_transaction(signed.raw_transaction))
        return len(self.hashes) - 1

    def mine(self) -> list[Any]:
        w3 = self.chain.w3
        w3.provider.make_request("evm_mine", [])
        w3.provider.make_request("evm_setAutomine", [True])
        return [w3.eth.get_transaction_receipt(h) for h in self.hashes]


@pytest.fixture(scope="module")
def anvil_platform(anvil_url: str) -> Platform:
    return make_platform(Chain.rpc(anvil_url, n_dev_accounts=24))


@pytest.fixture
def ap(anvil_platform: Platform) -> Iterator[Platform]:
    """The anvil platform, rolled back after each test (automining on again)."""
    snap = anvil_platform.chain.snapshot()
    try:
        yield anvil_platform
    finally:
        anvil_platform.chain.w3.provider.make_request("evm_setAutomine", [True])
        anvil_platform.chain.revert(snap)


@pytest.fixture
def race(ap: Platform) -> tuple[Platform, int, list[str], OneBlock]:
    """One task on anvil, two workers who accepted it, and a block to race in."""
    tid, offered = two_accepted_offers(ap, actors_of(ap.chain), DOMAIN, 2 * ACCEPT_WINDOW, REWARD)
    return ap, tid, offered, OneBlock(ap)


def test_a_copied_outcome_cid_loses_the_race(race) -> None:
    p, tid, (producer, copier), block = race
    p.tmc.commit_cid(producer, CID)  # before the upload: nobody has seen the CID yet
    # the producer's reveal is pending; the copier reads CID there and races it, paying more
    reveal = block.send(p.tmc, "submitOutcome", tid, CID, sender=producer, tip=1)
    commit = block.send(p.tmc, "commitCid", cid_commitment(CID, copier), sender=copier, tip=10)
    steal = block.send(p.tmc, "submitOutcome", tid, CID, sender=copier, tip=10)
    receipts = block.mine()
    assert len({r["blockNumber"] for r in receipts}) == 1, "one block"
    order = [r["transactionIndex"] for r in receipts]
    assert order[commit] < order[steal] < order[reveal], "the copier's two are mined first"
    assert receipts[commit]["status"] == 1
    assert receipts[steal]["status"] == 0, "a commitment of this block cannot be revealed"
    assert receipts[reveal]["status"] == 1
    assert p.tmc.outcome_of(CID) == (producer, tid, Verdict.PENDING)
    # a block later the copier's commitment is ripe, and the outcome record refuses it
    p.chain.await_block_after(receipts[commit]["blockNumber"])
    reverts("TasksDuplicateOutcome", p.tmc.transact, "submitOutcome", tid, CID, sender=copier)


def test_a_copied_model_cid_loses_the_race(race) -> None:
    """The same race for a model listing (an own upload, no outcome): the producer's
    addModel is pending, the copier commits and lists it first in that block."""
    p, _, (producer, copier), block = race
    p.tmc.commit_cid(producer, CID)
    listing = block.send(p.mmc, "addModel", CID, "", DOMAIN, [1], sender=producer, tip=1)
    block.send(p.tmc, "commitCid", cid_commitment(CID, copier), sender=copier, tip=10)
    steal = block.send(p.mmc, "addModel", CID, "", DOMAIN, [1], sender=copier, tip=10)
    receipts = block.mine()
    assert receipts[steal]["transactionIndex"] < receipts[listing]["transactionIndex"]
    assert receipts[steal]["status"] == 0 and receipts[listing]["status"] == 1
    model_id = p.mmc.model_of_cid(CID)
    assert p.mmc.call("getModel", model_id)[0][0] == producer


def test_a_reveal_needs_its_own_earlier_commitment(p, two_accepted) -> None:
    tid, (w0, w1) = two_accepted
    mine = cid_commitment(CID, w0)
    assert p.tmc.call("cidCommitment", CID, w0) == mine  # the Python formula is the contract's
    err = reverts("TasksCidNotCommitted", p.tmc.transact, "submitOutcome", tid, CID, sender=w0)
    assert err.args_dict == {"commitment": mine}
    p.tmc.commit_cid(w1, CID)  # someone else's commitment of the same CID is not w0's
    reverts("TasksCidNotCommitted", p.tmc.transact, "submitOutcome", tid, CID, sender=w0)
    reverts("ModelsCidNotCommitted", p.mmc.transact, "addModel", CID, "", DOMAIN, [1], sender=w0)
    rc = p.tmc.commit_cid(w0, CID)
    assert rc.one("CidCommitted").args["commitment"] == mine
    assert p.tmc.call("cidCommits", mine) == rc.block_number
    again = p.tmc.commit_cid(w0, CID)  # a retry after a crash keeps the first block
    assert again.named("CidCommitted") == [] and p.tmc.call("cidCommits", mine) == rc.block_number
    p.tmc.transact("submitOutcome", tid, CID, sender=w0)
    assert p.tmc.call("cidCommits", mine) == 0, "spent by the reveal"


def test_only_workers_commit(p, actors) -> None:
    reverts("TasksNotWorker", p.tmc.transact, "commitCid", b"\x01" * 32, sender=actors.outsider)


class _HeadOnlyNode:
    """A node like Besu: no pending block of its own (``number`` null) and a new head only
    every block period (here: every ``every`` polls; 0: never)."""

    def __init__(self, head: int, every: int) -> None:
        self.head, self.every, self.polls = head, every, 0

    @property
    def block_number(self) -> int:
        self.polls += 1
        if self.every and self.polls % self.every == 0:
            self.head += 1
        return self.head

    def get_block(self, tag: str) -> dict[str, Any]:
        assert tag == "pending"
        return {"number": None}


def test_a_reveal_waits_for_the_next_block_where_pending_is_the_head(monkeypatch) -> None:
    """``Chain.await_block_after`` on a node whose pending block is its head: it returns only
    once the head is past the commitment's block (the reveal then runs in a later block), and
    gives up with a TimeoutError when no block comes."""
    monkeypatch.setattr("backend.chain.client.time.sleep", lambda s: None)
    node = _HeadOnlyNode(head=7, every=3)
    chain = Chain.__new__(Chain)
    chain._tester = None
    chain.w3 = type("W3", (), {"eth": node})()
    assert chain.await_block_after(7) == 8 and node.polls >= 3
    stuck = _HeadOnlyNode(head=9, every=0)
    chain.w3 = type("W3", (), {"eth": stuck})()
    with pytest.raises(TimeoutError, match="no block after 9"):
        chain.await_block_after(9, timeout=0.05)
