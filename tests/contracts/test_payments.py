"""Payouts against hostile receivers: a worker contract that re-enters withdraw() is paid
exactly once (the reentrancy guard rejects the inner call), and one that rejects payments
keeps its credit (the withdrawal reverts as a whole)."""

from __future__ import annotations

import pytest
from eth_utils import keccak

from backend.chain.platform import cid_commitment

from .conftest import DOMAIN
from .helpers import CID, reverts

REWARD = 10**15
REENTER, REJECT = 1, 2


@pytest.fixture
def paid_probe(p, actors):
    """A ReentrantWorker contract registered as a worker with one reward credited on the TMC
    and one model price credited on the MMC."""
    probe, _ = p.chain.deploy("ReentrantWorker", sender=actors.outsider)

    def as_probe(handle, fn, *args):
        data = handle.contract.encode_abi(fn, list(args))
        return probe.transact("forward", handle.address, data, sender=actors.outsider)

    as_probe(p.umc, "addWorker", 1 << DOMAIN, 64, 64, 1)
    p.umc.add_requester(actors.requester)
    tid, _ = p.tmc.add_task(
        actors.requester, domain=DOMAIN, num_workers=1, reward=REWARD, duration=86_400
    )
    assert p.tmc.allocate(actors.requester, tid)[0] == [probe.address]
    as_probe(p.tmc, "acceptOffer", tid)
    as_probe(p.tmc, "commitCid", cid_commitment(CID, probe.address))  # mined in its own block
    as_probe(p.tmc, "submitOutcome", tid, CID)
    p.tmc.transact("reviewOutcome", tid, probe.address, 5, True, sender=actors.requester)
    as_probe(p.mmc, "addModel", CID, "", DOMAIN, [1])
    p.mmc.allocate(actors.requester, domain=DOMAIN, num_models=1, env=[1], price=REWARD)
    return probe, as_probe


@pytest.mark.parametrize("contract", ["tmc", "mmc"])
def test_reentrant_withdraw_pays_once(p, paid_probe, contract) -> None:
    probe, as_probe = paid_probe
    handle = getattr(p, contract)
    probe.transact("setMode", REENTER, sender=p.chain.accounts[-1])
    before = p.chain.balance(handle.address)
    as_probe(handle, "withdraw")
    assert probe.call("received") == REWARD
    assert p.chain.balance(handle.address) == before - REWARD
    assert handle.call("credits", probe.address) == 0
    assert probe.call("reentryOk") is False
    assert probe.call("reentrySelector") == keccak(text="ReentrancyGuardReentrantCall()")[:4]


@pytest.mark.parametrize(
    ("contract", "error"), [("tmc", "TasksTransferFailed"), ("mmc", "ModelsTransferFailed")]
)
def test_rejected_payment_keeps_credit(p, paid_probe, contract, error) -> None:
    probe, as_probe = paid_probe
    handle = getattr(p, contract)
    probe.transact("setMode", REJECT, sender=p.chain.accounts[-1])
    err = reverts(error, as_probe, handle, "withdraw")
    assert err.args_dict == {"account": probe.address, "amount": REWARD}
    assert handle.call("credits", probe.address) == REWARD
