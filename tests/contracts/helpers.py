"""Small helpers shared by the contract tests."""

from __future__ import annotations

import base64
import hashlib
from collections.abc import Callable
from typing import Any

import pytest

from backend.chain import errors

CID = "bafkreidot3j5vvbthwtydmn3ny2pq2ckibhbuj5sech6wpzsxokrkqntsy"


def cid_for(seed: object) -> str:
    """A CID text the contracts accept (lowercase base32 CIDv1, like the store's), distinct
    for distinct seeds, for tests that list many models."""
    digest = hashlib.sha256(repr(seed).encode()).digest()
    return "bafkrei" + base64.b32encode(digest).decode().lower().rstrip("=")[:52]


def reverts(name: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> errors.ContractError:
    """Call ``fn`` and assert it reverts with custom error ``name``; returns the error."""
    with pytest.raises(errors.get(name)) as info:
        fn(*args, **kwargs)
    return info.value


def two_accepted(
    p: Any, actors: Any, domain: int, duration: int, reward: int
) -> tuple[int, list[str]]:
    """A requester and three workers of ``domain`` registered, one task of two slots posted
    and allocated, both offerees accepted: (task id, [offeree 0, offeree 1])."""
    p.umc.add_requester(actors.requester)
    for w in actors.workers[:3]:
        p.umc.add_worker(w, [domain], 4, 16, 1)
    tid, _ = p.tmc.add_task(
        actors.requester, domain=domain, num_workers=2, reward=reward, duration=duration
    )
    offered, _ = p.tmc.allocate(actors.requester, tid)
    for w in offered:
        p.tmc.transact("acceptOffer", tid, sender=w)
    return tid, offered
