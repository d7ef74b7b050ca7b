"""Held-out pass (restarts and real services): a chain that reorganises while the indexer reads a
range of blocks. The node answers ``eth_getLogs`` from one branch and the block hashes from
another; before the fix the index kept the logs of the lost branch under the hashes of the new
one, so no later poll noticed (``check_continuity`` compares hashes) and the index held events
the chain never had, for good."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from sqlalchemy.orm import Session, sessionmaker

from backend.db import make_engine, make_sessionmaker, upgrade
from backend.indexer import Indexer
from backend.services.chain import ChainService
from tests.gateway.test_indexer import _activity, _chain_events, _indexed
from tests.gateway.test_indexer_durability import _chain_tx_hashes, _tx_hashes


@pytest.fixture
def sessions(tmp_path: Path) -> sessionmaker[Session]:
    engine = make_engine(f"sqlite:///{tmp_path / 'idx.sqlite'}")
    upgrade(engine)
    return make_sessionmaker(engine)


def test_a_reorg_between_the_logs_and_the_block_hashes_is_not_indexed(
    service: ChainService, sessions: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    offers: list[tuple[int, str]] = []
    idx = Indexer(service, sessions, on_offer=lambda t, w: offers.append((t, w)))
    idx.poll()  # the index is at the head
    fork = service.chain.snapshot()
    _activity(service, 1)  # branch A: requester user1, workers user2..4
    eth = service.chain.w3.eth
    real_get_logs = eth.get_logs
    reorged = []

    def get_logs_then_reorg(params: Any) -> Any:
        logs = real_get_logs(params)
        if not reorged:  # the node switches to branch B right after answering from A
            reorged.append(True)
            service.chain.revert(fork)
            _activity(service, 9)  # branch B: the same number of blocks, other accounts
        return logs

    monkeypatch.setattr(eth, "get_logs", get_logs_then_reorg)
    try:
        idx.poll()
    except Exception:  # noqa: S110 - a poll may give up on a moving chain; the next one must fix it
        pass
    monkeypatch.setattr(eth, "get_logs", real_get_logs)
    idx.poll()
    assert reorged
    assert _indexed(sessions) == _chain_events(service)
    assert _tx_hashes(sessions) == _chain_tx_hashes(service)  # only branch B's events
    keys = service.demo_keys
    assert keys is not None
    branch_b_workers = {keys.address(f"user{i}") for i in (10, 11, 12)}
    assert offers and {w for _, w in offers} <= branch_b_workers  # no offer of branch A
