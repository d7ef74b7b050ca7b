"""Small helpers shared by the contract tests."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from backend.chain import errors

CID = "bafkreidot3j5vvbthwtydmn3ny2pq2ckibhbuj5sech6wpzsxokrkqntsy"


def reverts(name: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> errors.ContractError:
    """Call ``fn`` and assert it reverts with custom error ``name``; returns the error."""
    with pytest.raises(errors.get(name)) as info:
        fn(*args, **kwargs)
    return info.value
