"""Held-out pass on commit-reveal in the worker daemon: an outcome's commitment lost from the
chain (a deep reorg after the upload) is committed again, a bounded number of times, instead
of failing a job whose model is uploaded and whose deadline is ahead."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest
import torch

from backend.chain.platform import OfferState
from workers.daemon.handler import MAX_RECOMMITS, OfferHandler

from .helpers import post_task

torch.set_num_threads(1)


def handler_for(p: Any, address: str, store: Any, tmp_path: Path) -> OfferHandler:
    h = OfferHandler(account=p.chain._keys[address], platform=p, store=store,
                     data_dir=tmp_path / "w" / address)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    return h


def lose_the_first_commitment(p: Any, h: OfferHandler, monkeypatch: pytest.MonkeyPatch,
                              *, later_ones_too: bool = False) -> list[str]:
    """Snapshot the chain before the first commitCid, and go back to that snapshot just before
    the reveal (``_flush_progress`` runs between them): the blocks holding the commitment are
    gone, as after a reorg deeper than the receipt wait. With ``later_ones_too`` every later
    commitment is lost as well (it never lands). Returns the CIDs committed, in order."""
    committed: list[str] = []
    snapshots: list[Any] = []
    real_commit = p.tmc.commit_cid

    def commit(sender: str, cid: str) -> Any:
        committed.append(cid)
        if not snapshots:
            snapshots.append(p.chain.snapshot())
        elif later_ones_too:
            return None
        return real_commit(sender, cid)

    def reorg_before_reveal(task_id: int, wait_s: float) -> None:
        if snapshots and snapshots[-1] is not None:
            p.chain.revert(snapshots[-1])
            snapshots.append(None)

    monkeypatch.setattr(p.tmc, "commit_cid", commit)
    monkeypatch.setattr(h, "_flush_progress", reorg_before_reveal)
    return committed


def test_an_outcome_commitment_lost_in_a_reorg_is_committed_again(
    env: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """The reveal reverted with TasksCidNotCommitted and the job failed, though its model was
    uploaded and its offer still accepted."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)
    committed = lose_the_first_commitment(p, h, monkeypatch)
    with caplog.at_level(logging.WARNING, logger="workers.daemon.handler"):
        out = h.handle(task_id, worker)
    assert out["status"] == "submitted", out
    assert committed == [out["cid"], out["cid"]]  # the same CID, committed twice
    assert p.tmc.offer(task_id, worker)["state"] == OfferState.SUBMITTED
    assert p.tmc.outcome_of(out["cid"])[:2] == (worker, task_id)
    assert h._state(task_id)["recommits"] == 1
    assert "no longer on chain" in caplog.text and f"1 of {MAX_RECOMMITS}" in caplog.text


def test_a_commitment_that_never_lands_fails_the_job_after_bounded_recommits(
    env: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)
    committed = lose_the_first_commitment(p, h, monkeypatch, later_ones_too=True)
    out = h.handle(task_id, worker)
    assert out["status"] == "failed", out
    assert len(committed) == 1 + MAX_RECOMMITS
    state = h._state(task_id)
    assert "TasksCidNotCommitted" in state["reason"] and state["recommits"] == MAX_RECOMMITS
