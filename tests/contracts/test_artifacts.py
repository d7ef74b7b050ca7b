"""Build artifacts: staleness check (hash of sources + compiler settings) and the custom-error
registry used to turn revert data into typed exceptions."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from eth_abi import encode
from eth_utils import keccak

from backend.chain import errors
from backend.chain.artifacts import (
    CONTRACTS_DIR,
    PLATFORM_CONTRACTS,
    StaleArtifactsError,
    check_artifacts,
    source_hash,
)


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    """A copy of the hashed inputs and the artifacts of contracts/."""
    root = tmp_path / "contracts"
    root.mkdir()
    for name in ("package.json", "solc-settings.json"):
        shutil.copy(CONTRACTS_DIR / name, root / name)
    shutil.copytree(CONTRACTS_DIR / "src", root / "src")
    shutil.copytree(CONTRACTS_DIR / "build", root / "build")
    return root


def test_committed_artifacts_are_fresh() -> None:
    h = check_artifacts()
    for name in PLATFORM_CONTRACTS:
        art = json.loads((CONTRACTS_DIR / "build" / f"{name}.json").read_text())
        assert art["sourceHash"] == h and art["bytecode"].startswith("0x60")
        assert art["compiler"].startswith("0.8.")


def test_modified_source_makes_artifacts_stale(tree: Path) -> None:
    assert check_artifacts(tree) == source_hash(tree)
    src = tree / "src" / "TasksManager.sol"
    src.write_text(src.read_text() + "\n// edited\n")
    with pytest.raises(StaleArtifactsError, match="build.mjs"):
        check_artifacts(tree)


@pytest.mark.parametrize("change", ["settings", "new_source", "removed_source", "package"])
def test_every_hashed_input_counts(tree: Path, change: str) -> None:
    before = source_hash(tree)
    if change == "settings":
        s = json.loads((tree / "solc-settings.json").read_text())
        s["optimizer"]["runs"] += 1
        (tree / "solc-settings.json").write_text(json.dumps(s))
    elif change == "new_source":
        (tree / "src" / "Extra.sol").write_text("// SPDX-License-Identifier: MIT\n")
    elif change == "removed_source":
        (tree / "src" / "QoSMath.sol").unlink()
    else:
        pkg = json.loads((tree / "package.json").read_text())
        pkg["dependencies"]["solc"] = "0.8.30"
        (tree / "package.json").write_text(json.dumps(pkg))
    assert source_hash(tree) != before
    with pytest.raises(StaleArtifactsError):
        check_artifacts(tree)


def test_missing_artifact_is_reported(tree: Path) -> None:
    (tree / "build" / "ModelsManager.json").unlink()
    with pytest.raises(FileNotFoundError, match="build.mjs"):
        check_artifacts(tree)


def test_custom_errors_decode_with_arguments() -> None:
    sel = keccak(text="TasksNotOfferedWorker(uint256,address)")[:4]
    worker = "0x" + "ab" * 20
    exc = errors.decode_revert(sel + encode(["uint256", "address"], [7, worker]))
    assert isinstance(exc, errors.get("TasksNotOfferedWorker"))
    assert isinstance(exc, errors.ContractError)
    assert exc.args_dict["taskId"] == 7 and exc.args_dict["worker"].lower() == worker
    assert "TasksNotOfferedWorker(taskId=7" in str(exc)
    assert isinstance(errors.decode_revert(b"\x12\x34\x56\x78"), errors.UnknownRevert)
    assert isinstance(errors.decode_revert(None), errors.UnknownRevert)
    panic = errors.decode_revert(keccak(text="Panic(uint256)")[:4] + encode(["uint256"], [0x11]))
    assert isinstance(panic, errors.Panic) and panic.args_dict["code"] == 0x11
    from backend.chain.errors import UsersNotWorker  # module-level lookup by name

    assert UsersNotWorker is errors.get("UsersNotWorker")
    with pytest.raises(KeyError, match="known"):
        errors.get("NoSuchError")


def test_every_error_has_a_component_prefix_and_unique_selector() -> None:
    sel = errors.selectors()
    ours = [n for n in sel if n not in {"Error", "Panic"}]
    prefixes = ("Users", "Tasks", "Models", "ReentrancyGuard")
    assert ours and all(n.startswith(prefixes) for n in ours), ours
    assert len(set(sel.values())) == len(sel)
