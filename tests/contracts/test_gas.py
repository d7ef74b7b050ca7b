"""Gas report: structure, intrinsic-gas arithmetic and the thesis Table 7.5 targets."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from backend.chain.commands import app
from backend.chain.gas import THESIS_TABLE_7_5, gas_report, intrinsic_gas


def test_intrinsic_gas_counts_calldata_and_creation() -> None:
    assert intrinsic_gas(b"") == 21_000
    assert intrinsic_gas(b"\x00\x01") == 21_000 + 4 + 16
    assert intrinsic_gas(b"\x01" * 33, create=True) == 21_000 + 16 * 33 + 32_000 + 2 * 2


@pytest.fixture(scope="module")
def report() -> dict:
    return gas_report(workers=5, scaling=(5, 7))


def test_report_covers_every_function(report) -> None:
    f = report["functions"]
    assert set(THESIS_TABLE_7_5) - {"UMC.addRequester"} <= set(f)
    for name, row in f.items():
        assert 0 < row["execution_gas"] < row["gas_used"], name
    assert set(report["allocation_growth_gas_used"]["allocateTask"]) == {"5", "7"}


def test_per_call_functions_beat_thesis(report) -> None:
    """Execution gas at or below thesis Table 7.5 for every non-deployment function except
    addWorker (first worker of a domain pays for new storage slots; see the report)."""
    f = report["functions"]
    for name in (
        "UMC.updateStatus",
        "UMC.updateInfo",
        "UMC.getWorkers",
        "TMC.addTask",
        "TMC.allocateTask",
        "TMC.updateTaskStatus",
        "MMC.addModel",
        "MMC.allocateModel",
    ):
        assert f[name]["execution_gas"] <= THESIS_TABLE_7_5[name], name


def test_allocation_gas_grows_with_candidates(report) -> None:
    g = report["allocation_growth_gas_used"]
    for fn in ("allocateTask", "allocateModel", "allocateModel(Eq. 12)"):
        assert g[fn]["7"] > g[fn]["5"], fn


def test_cli_prints_one_json_object(report, monkeypatch) -> None:
    """The command prints the report as a single JSON object (report reused: no second
    chain run) and rejects a malformed --scaling."""
    seen = {}

    def fake(workers, scaling, seed):
        seen.update(workers=workers, scaling=scaling, seed=seed)
        return report

    monkeypatch.setattr("backend.chain.gas.gas_report", fake)
    res = CliRunner().invoke(app, ["gas-report", "--workers", "7", "--scaling", "7,9", "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout) == json.loads(json.dumps(report))
    assert seen == {"workers": 7, "scaling": (7, 9), "seed": 0}
    table = CliRunner().invoke(app, ["gas-report"])
    assert "TMC.allocateTask" in table.stdout and table.exit_code == 0
    bad = CliRunner().invoke(app, ["gas-report", "--scaling", "a,b"])
    assert bad.exit_code != 0
