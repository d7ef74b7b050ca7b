"""`drlaas chain ...` commands (the lead mounts :data:`app` under ``drlaas chain``)."""

from __future__ import annotations

import json
from typing import Annotated

import typer

app = typer.Typer(help="Consortium-chain contracts (UMC, TMC, MMC): gas and artifacts.")


@app.command("gas-report")
def gas_report_cmd(
    workers: Annotated[
        int, typer.Option(help="candidate pool for allocateTask/allocateModel")
    ] = 50,
    scaling: Annotated[
        str, typer.Option(help="comma-separated pool sizes for allocation growth")
    ] = "50,200,600",
    as_json: Annotated[bool, typer.Option("--json", help="one JSON object on stdout")] = False,
    seed: Annotated[int, typer.Option(help="seed of the random worker attributes")] = 0,
) -> None:
    """Deploy on the embedded chain, run every function and report gas (thesis Table 7.5)."""
    from .gas import gas_report

    try:
        sizes = tuple(int(s) for s in scaling.split(",") if s.strip())
    except ValueError:
        raise typer.BadParameter(
            f"--scaling must be comma-separated integers, got {scaling!r}"
        ) from None
    report = gas_report(workers=workers, scaling=sizes, seed=seed)
    if as_json:
        typer.echo(json.dumps(report, sort_keys=True))
        return
    typer.echo(f"{'function':32s} {'gasUsed':>10s} {'execution':>10s} {'thesis':>10s}")
    for name, row in report["functions"].items():
        thesis = row.get("thesis")
        typer.echo(
            f"{name:32s} {row['gas_used']:>10,d} {row['execution_gas']:>10,d} "
            f"{(f'{thesis:,d}' if thesis else '-'):>10s}"
        )
    for fn, points in report["allocation_growth_gas_used"].items():
        shown = ", ".join(f"{n}: {g:,d}" for n, g in points.items())
        typer.echo(f"{fn} gasUsed by candidates -> {shown}")


@app.command("check-artifacts")
def check_artifacts_cmd() -> None:
    """Fail (exit 1) when contracts/build is stale with respect to contracts/src."""
    from .artifacts import StaleArtifactsError, check_artifacts

    try:
        h = check_artifacts()
    except (StaleArtifactsError, FileNotFoundError) as exc:
        typer.echo(str(exc), err=True)
        raise typer.Exit(1) from None
    typer.echo(f"artifacts up to date (source hash {h})")
