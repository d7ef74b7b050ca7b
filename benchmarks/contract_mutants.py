"""Do the Foundry invariants catch seeded bugs? (issue 8: a mutation check of the stateful
invariant tests in contracts/test/invariant).

Each mutant is one small edit to a contract in a scratch copy of ``contracts/`` (the repository
is never touched): money credited wrong, a change without its event, a role check removed, the
greedy top-k broken. For each, ``forge test --match-path 'test/invariant/*'`` runs with the
project's settings (10,000 handler calls per invariant, fixed seed); a mutant is *killed* when
a test fails. The unmutated copy must pass first. Prints a table and the kill ratio.

Usage: python benchmarks/contract_mutants.py [--only NAME,...] [--all-tests]
       (~70 s per mutant on 2 cores; --all-tests: the fuzz tests as well)
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONTRACTS = ROOT / "contracts"

# name: (file under src/, exact text (must occur once), replacement, what the bug is)
MUTANTS: dict[str, tuple[str, str, str, str]] = {
    "tmc-credit-extra-wei": (
        "TasksManager.sol", "credits[account] += amount;", "credits[account] += amount + 1;",
        "a payment credits 1 wei more than it moves out of escrow"),
    "tmc-credit-silent": (
        "TasksManager.sol", "emit PaymentCredited(account, taskId, amount);", "",
        "a credit without its PaymentCredited event"),
    "tmc-review-by-anyone": (
        "TasksManager.sol",
        "Task storage t = _tasks[taskId];\n        _checkRequester(t, taskId);\n"
        "        Offer storage o = _offers[taskId][worker];\n"
        "        if (o.state != OfferState.Submitted)",
        "Task storage t = _tasks[taskId];\n        Offer storage o = _offers[taskId][worker];\n"
        "        if (o.state != OfferState.Submitted)",
        "reviewOutcome no longer checks that the caller is the task's requester"),
    "tmc-submit-unaccepted": (
        "TasksManager.sol",
        "if (o.state != OfferState.Accepted) revert TasksNotAssignedWorker(taskId, msg.sender);\n"
        "        if (bytes(cid).length == 0)",
        "if (bytes(cid).length == 0)",
        "submitOutcome no longer checks that the caller accepted the task"),
    "tmc-reveal-uncommitted": (
        "TasksManager.sol",
        "if (!_committedBefore(commitment)) revert TasksCidNotCommitted(commitment);", "",
        "submitOutcome takes a CID nobody committed (commit-reveal off: front-running works)"),
    "tmc-reveal-same-block": (
        "TasksManager.sol", "return committedAt != 0 && committedAt < block.number;",
        "return committedAt != 0 && committedAt <= block.number;",
        "a commitment is revealable in its own block (a copier races it into one block)"),
    "mmc-list-uncommitted": (
        "ModelsManager.sol",
        "if (!tmc.committedBefore(commitment)) revert ModelsCidNotCommitted(commitment);", "",
        "addModel lists an own upload nobody committed"),
    "qos-first-k-not-top-k": (
        "QoSMath.sol", "} else if (k != 0 && q > qs[k - 1]) {", "} else if (false) {",
        "the greedy selection keeps the first k candidates, not the k best"),
    "mmc-credit-half": (
        "ModelsManager.sol", "credits[account] += amount;", "credits[account] += amount / 2;",
        "a model owner is credited half of the price paid"),
    "mmc-review-by-anyone": (
        "ModelsManager.sol",
        "if (a.requester != msg.sender) revert ModelsNotAllocationRequester(allocId, msg.sender);",
        "", "updateModelRep no longer checks that the caller bought the allocation"),
}


def scratch_copy() -> Path:
    """contracts/ without build output, node_modules linked (solc-js and OpenZeppelin)."""
    tmp = Path(tempfile.mkdtemp(prefix="drlaas-mutants-"))
    for name in ("src", "test", "foundry"):
        shutil.copytree(CONTRACTS / name, tmp / name)
    shutil.copy2(CONTRACTS / "foundry.toml", tmp / "foundry.toml")
    (tmp / "node_modules").symlink_to(CONTRACTS / "node_modules")
    return tmp


def run_invariants(workdir: Path, all_tests: bool = False) -> tuple[bool, list[str], float]:
    """(passed, failing test names, seconds) of the invariant suite in ``workdir`` (with
    ``all_tests``: every forge test but the gas snapshot, i.e. the fuzz tests too)."""
    env = dict(os.environ)
    env["PATH"] = f"{CONTRACTS / 'node_modules' / '.bin'}:{ROOT / '.venv' / 'bin'}:{env['PATH']}"
    t0 = time.perf_counter()
    which = (["--no-match-contract", "GasTest"] if all_tests
             else ["--match-path", "test/invariant/*"])
    out = subprocess.run(["forge", "test", *which], cwd=workdir, env=env, capture_output=True,
                         text=True)
    text = out.stdout + out.stderr
    # forge lists the failures after "Failing tests:"; an invariant's name follows its
    # shrunk call sequence, a test's its [FAIL: reason]
    section = text.split("Failing tests:", 1)[1] if "Failing tests:" in text else ""
    failing = sorted(set(re.findall(r"\b((?:invariant|test)\w*)\(", section)))
    if out.returncode != 0 and not failing:
        failing = ["(build or run error) " + text.strip().splitlines()[-1][:120]]
    return out.returncode == 0, failing, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--only", default="", help="comma-separated mutant names (default: all)")
    p.add_argument("--all-tests", action="store_true",
                   help="run every forge test (fuzz tests too), not only the invariants")
    args = p.parse_args(argv)
    names = [n for n in args.only.split(",") if n] or list(MUTANTS)
    unknown = [n for n in names if n not in MUTANTS]
    if unknown:
        p.error(f"unknown mutants {unknown}; known: {', '.join(MUTANTS)}")
    base = scratch_copy()
    try:
        ok, failing, secs = run_invariants(base, args.all_tests)
        if not ok:
            print(f"the unmutated contracts fail the invariants ({failing}): fix that first")
            return 1
        print(f"unmutated: invariants pass ({secs:.0f} s)", file=sys.stderr, flush=True)
        rows, killed = [], 0
        for name in names:
            file, old, new, what = MUTANTS[name]
            work = scratch_copy()
            try:
                path = work / "src" / file
                src = path.read_text()
                if src.count(old) != 1:
                    raise SystemExit(f"mutant {name}: its text occurs {src.count(old)} times in "
                                     f"{file}; update MUTANTS to the current source")
                path.write_text(src.replace(old, new))
                ok, failing, secs = run_invariants(work, args.all_tests)
            finally:
                shutil.rmtree(work, ignore_errors=True)
            killed += not ok
            rows.append((name, what, "killed" if not ok else "SURVIVED", failing, secs))
            print(f"{name}: {'killed' if not ok else 'survived'} {failing} ({secs:.0f} s)",
                  file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(base, ignore_errors=True)
    print("| mutant | bug | result | failing invariants |")
    print("|---|---|---|---|")
    for name, what, result, failing, _ in rows:
        print(f"| {name} | {what} | {result} | {', '.join(failing) or '-'} |")
    print(f"\nkilled {killed} of {len(rows)} mutants ({killed / len(rows):.0%})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
