"""`drlaas zoo`: list and retrain the shipped models of `models/` (workers/mdrl/zoo.py)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(no_args_is_help=True, help="The model zoo: one trained model per thesis row.")

SHIPPED_MODELS = Path(__file__).resolve().parents[3] / "models"
"""The zoo shipped with the project (``models/`` of the checkout this package runs from), so
that ``zoo list`` finds it from any directory."""


@app.command("list")
def list_command(
    models: Annotated[
        Path | None, typer.Option(help="Zoo directory (default: the project's models/).")
    ] = None,
) -> None:
    """Each zoo model: preset, budget, and its card's held-out figures if trained."""
    from workers.mdrl.zoo import ZOO

    if models is None:
        models = SHIPPED_MODELS
        if not models.is_dir():
            raise typer.BadParameter(
                f"no shipped models at {models} (this install has no project checkout); give "
                "the zoo directory with --models DIR", param_hint="--models")
    if not models.is_dir():
        raise typer.BadParameter(f"{models}: no such directory", param_hint="--models")
    for name, entry in ZOO.items():
        card = models / name / "model.json"
        figures = ""
        if card.is_file():
            try:
                doc = json.loads(card.read_text())
                held = doc.get("zoo", {}).get("heldout", {})
                figures = "  ".join(
                    f"{r}: time {held[r]['time']:.2f} cost {held[r]['cost']:.2f}"
                    for r in ("poisson", "expected") if r in held)
            except (ValueError, AttributeError, KeyError, TypeError) as exc:
                figures = f"(unreadable card {card}: {exc})"  # the other entries still list
        typer.echo(f"{name:12s} {entry.preset:18s} {entry.minutes:5.1f} min  {figures}")


@app.command("train")
def train_command(
    names: Annotated[list[str] | None, typer.Argument(help="Zoo models (default: all).")] = None,
    models: Annotated[Path, typer.Option(help="Where the trained models go.")] = Path("models"),
    runs: Annotated[Path, typer.Option(help="Run directories (checkpoints; resumable).")
                    ] = Path("runs/zoo"),
    minutes: Annotated[float | None, typer.Option(help="Override each model's budget.")] = None,
    progress: Annotated[bool, typer.Option(help="Show progress bars.")] = True,
) -> None:
    """Train (or resume) zoo models and write them with their held-out figures."""
    from workers.mdrl.zoo import ZOO, train_entry

    chosen = names or list(ZOO)
    unknown = [n for n in chosen if n not in ZOO]
    if unknown:
        raise typer.BadParameter(f"unknown zoo model(s) {unknown}; known: {', '.join(ZOO)}")
    for name in chosen:
        target = train_entry(name, models, runs, minutes=minutes, progress=progress)
        held = json.loads((target / "model.json").read_text())["zoo"]["heldout"]
        typer.echo(json.dumps({"model": str(target), **{r: {k: held[r][k] for k in
                   ("success", "time", "cost", "oracle_time")} for r in ("poisson", "expected")}}))


@app.command("publish")
def publish_command(
    name: Annotated[str, typer.Argument(help="The zoo model the run trained.")],
    run: Annotated[Path, typer.Option(help="A finished run directory (drlaas train --out).")],
    models: Annotated[Path, typer.Option(help="Zoo directory.")] = Path("models"),
) -> None:
    """Write models/NAME from a finished `drlaas train` run of that zoo entry (same preset,
    seed and experts, checked), with its held-out figures and training curve."""
    from workers.mdrl.zoo import ZOO, publish_run

    if name not in ZOO:
        raise typer.BadParameter(f"unknown zoo model {name!r}; known: {', '.join(ZOO)}")
    if not (run / "model" / "model.json").is_file() or not (run / "metrics.csv").is_file():
        raise typer.BadParameter(f"{run} holds no finished run (model/model.json, metrics.csv)")
    try:
        target = publish_run(name, run, models)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--run") from None
    held = json.loads((target / "model.json").read_text())["zoo"]["heldout"]
    typer.echo(json.dumps({"model": str(target), **{r: {k: held[r][k] for k in
               ("success", "time", "cost", "oracle_time")} for r in ("poisson", "expected")}}))


@app.command("complete")
def complete_command(
    names: Annotated[list[str] | None, typer.Argument(help="Zoo models (default: all).")] = None,
    models: Annotated[Path, typer.Option(help="Zoo directory.")] = Path("models"),
    runs: Annotated[Path | None, typer.Option(
        help="Run directories: also attach each model's training curve from RUNS/NAME.")] = None,
) -> None:
    """Bring cards made before cards had them up to date: the baselines' held-out figures (on
    the card's own episodes) and, with --runs, the training curve of the model's own run."""
    from workers.mdrl.zoo import ZOO, add_baselines, attach_run_curve

    unknown = [n for n in names or [] if n not in ZOO]
    if unknown:
        raise typer.BadParameter(f"unknown zoo model(s) {unknown}; known: {', '.join(ZOO)}")
    for name in names or [n for n in ZOO if (models / n / "model.json").is_file()]:
        try:
            held = add_baselines(models / name)
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
            raise typer.BadParameter(f"{models / name}: cannot complete its card ({exc})",
                                     param_hint="NAMES") from None
        line = {"model": name, "baselines": {r: {b: round(f["time"], 2) for b, f in
                                                 held[r]["baselines"].items()}
                                             for r in ("poisson", "expected") if r in held}}
        if runs is not None:
            line["curve_points"] = len(attach_run_curve(models / name, runs / name)["points"])
        typer.echo(json.dumps(line))
