"""`drlaas cae`: pre-train the Ch. 4 walls autoencoder and show its held-out error
(workers/mdrl/cae.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

import typer

app = typer.Typer(no_args_is_help=True,
                  help="Walls convolutional autoencoder (Ch. 4.3): train and evaluate.")

_COLUMNS = ("bce", "cell_error", "wall_iou", "exact")


def _grid(text: str) -> tuple[int, int]:
    """'30' -> (30, 30); '30x20' -> (30, 20)."""
    try:
        parts = [int(v) for v in text.lower().split("x")]
    except ValueError:
        parts = []
    if len(parts) == 1:
        parts *= 2
    if len(parts) != 2 or min(parts) < 4:
        raise typer.BadParameter(f"expected N or ROWSxCOLS with sides >= 4, got {text!r}",
                                 param_hint="--grid")
    return parts[0], parts[1]


def _walls(text: str) -> tuple[int, int]:
    """'2' -> (2, 2); '1:3' or '1-3' -> (1, 3)."""
    try:
        parts = [int(v) for v in text.replace("-", ":").split(":")]
    except ValueError:
        parts = []
    if len(parts) == 1:
        parts *= 2
    if len(parts) != 2 or not 0 <= parts[0] <= parts[1] or parts[1] < 1:
        raise typer.BadParameter(f"expected K or MIN:MAX with 0 <= MIN <= MAX and MAX >= 1, "
                                 f"got {text!r}", param_hint="--walls")
    return parts[0], parts[1]


def table(figures: dict[str, dict[str, Any]]) -> str:
    """Held-out figures as a text table: one row per predictor (CAE and baselines)."""
    head = f"{'predictor':10s}" + "".join(f"{c:>12s}" for c in _COLUMNS)
    lines = [head, "-" * len(head)]
    for name, row in figures.items():
        cells = "".join(f"{'-' if row.get(c) is None else format(row[c], '.5f'):>12s}"
                        for c in _COLUMNS)
        lines.append(f"{name:10s}{cells}")
    return "\n".join(lines)


def _check_out(out: Path) -> None:
    """Refuse an --out the CAE cannot or must not be written to, before training: a file or a
    path under one (the save failed after training), or a directory holding another kind of
    model (it was overwritten). A CAE directory is rewritten, as the shipped ones are built."""
    from workers.mdrl.cae import CARD, load_cae_card

    parent = out
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise typer.BadParameter(f"{parent} is a file, not a directory", param_hint="--out")
    if (out / CARD).is_file():
        try:
            load_cae_card(out)
        except (OSError, ValueError) as exc:
            raise typer.BadParameter(f"{out} holds a model that is not a walls CAE ({exc}): "
                                     "give another directory", param_hint="--out") from None


@app.command("train")
def train_command(
    out: Annotated[Path, typer.Option(help="Model directory (model.safetensors + model.json).")],
    grid: Annotated[str, typer.Option(help="Grid: N (N x N) or ROWSxCOLS.")] = "30",
    walls: Annotated[str, typer.Option(help="Walls per layout: K or MIN:MAX.")] = "1:3",
    preset: Annotated[str | None, typer.Option(help="Take the env spec (grid, walls, wall "
                                                    "lengths) from this preset instead.")] = None,
    layouts: Annotated[int, typer.Option(help="Layouts drawn (Table 4.1: 100000).")] = 20_000,
    epochs: Annotated[int, typer.Option(help="Passes over the training layouts.")] = 30,
    embedding: Annotated[int, typer.Option(help="Embedding size d (Table 4.1: 128).")] = 128,
    lr: Annotated[float, typer.Option(help="Adam learning rate (Table 4.1: 1e-3).")] = 1e-3,
    batch: Annotated[int, typer.Option(help="Minibatch size.")] = 128,
    heldout: Annotated[float, typer.Option(help="Held-out share of the layouts.")] = 0.1,
    pos_weight: Annotated[float, typer.Option(help="BCE weight of wall cells (walls are ~3% "
                                                   "of the cells; 1 = plain BCE).")] = 1.0,
    seed: Annotated[int, typer.Option(min=0, help="Seeds layouts, split, init and batch "
                                              "order.")] = 0,
    threads: Annotated[int, typer.Option(help="torch threads.")] = 1,
    progress: Annotated[bool, typer.Option(help="Show a progress bar.")] = True,
) -> None:
    """Train a walls CAE on the env's own layouts; prints held-out error vs the baselines."""
    import torch

    from workers.mdrl.cae import CAEDiverged, parameters, save_cae, train_cae
    from workers.mdrl.commands.train import usable_cpus
    from workers.mdrl.spec import EnvSpec

    if not 1 <= threads <= usable_cpus():
        raise typer.BadParameter(f"must be between 1 and {usable_cpus()} (the CPUs this process "
                                 f"may use), got {threads}", param_hint="--threads")
    if not (math.isfinite(pos_weight) and pos_weight > 0):
        raise typer.BadParameter(f"must be a finite number > 0, got {pos_weight}",
                                 param_hint="--pos-weight")
    _check_out(out)
    torch.set_num_threads(threads)
    if preset is not None:
        from workers.mdrl.presets import get_preset

        try:
            spec = get_preset(preset).env
        except (KeyError, ValueError) as exc:
            raise typer.BadParameter(str(exc), param_hint="--preset") from None
    else:
        rows, cols = _grid(grid)
        try:
            spec = EnvSpec(rows=rows, cols=cols, walls=_walls(walls))
        except ValueError as exc:  # e.g. a grid beyond spec.MAX_CELLS, more walls than fit
            raise typer.BadParameter(str(exc), param_hint="--grid / --walls") from None
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=epochs, unit="epoch", desc="cae", dynamic_ncols=True)

    def tick(epoch: int, loss: float) -> None:
        if bar is not None:
            bar.update(1)
            bar.set_postfix(train_bce=f"{loss:.4f}")

    try:
        model, info = train_cae(spec, layouts=layouts, epochs=epochs, embedding=embedding,
                                seed=seed, lr=lr, batch=batch, heldout=heldout,
                                pos_weight=pos_weight, progress=tick)
    except CAEDiverged as exc:  # nothing is saved
        raise typer.BadParameter(str(exc), param_hint="--lr") from None
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from None
    finally:
        if bar is not None:
            bar.close()
    save_cae(out, model, spec, info)
    size = (out / "model.safetensors").stat().st_size
    typer.echo(f"{out}: grid {spec.rows}x{spec.cols}, walls {spec.walls[0]}-{spec.walls[1]}, "
               f"d = {embedding}, {parameters(model.encoder)} encoder parameters, "
               f"{size / 1024:.0f} KiB, {info['training']['wall_time_s']:.0f} s")
    typer.echo(f"held-out layouts: {info['training']['heldout_layouts']} "
               f"({info['training']['heldout_also_in_train']:.1%} also drawn for training)")
    typer.echo(table(info["heldout"]))


@app.command("eval")
def eval_command(
    path: Annotated[Path, typer.Argument(help="CAE directory (model.json + model.safetensors).")],
    layouts: Annotated[int | None, typer.Option(help="Also score this many fresh layouts.")
                       ] = None,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the fresh layouts.")] = 1_000_003,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """The held-out figures of a trained CAE (its card), optionally re-measured on fresh
    layouts of the same env spec."""
    from workers.mdrl.cae import (
        baseline_figures,
        load_cae,
        load_cae_card,
        predict,
        reconstruction_figures,
        wall_layouts,
    )
    from workers.mdrl.spec import EnvSpec

    if layouts is not None and layouts < 2:
        raise typer.BadParameter(f"must be >= 2, got {layouts}", param_hint="--layouts")
    try:  # the whole CAE, not only its card: a damaged directory is named here, not mid-way
        card = load_cae_card(path)
        model = load_cae(path)
        spec = EnvSpec.from_dict(card["env"])
        if [spec.rows, spec.cols] != list(card["grid"]):
            raise ValueError(f"the card's env is {spec.rows}x{spec.cols} but its grid is "
                             f"{card['grid']}")
    except KeyError as exc:
        raise typer.BadParameter(f"{path}: the card has no {exc}", param_hint="PATH") from None
    except (OSError, ValueError, TypeError) as exc:
        raise typer.BadParameter(str(exc), param_hint="PATH") from None
    heldout = card.get("heldout")
    valid = isinstance(heldout, dict) and all(isinstance(v, dict) for v in heldout.values())
    result: dict[str, Any] = {"card": heldout if valid else {}}
    if layouts is not None:
        try:
            fresh = wall_layouts(spec, layouts, seed)
            other = wall_layouts(spec, layouts, seed + 1)  # the mean map: from other layouts
        except ValueError as exc:  # more layouts than memory holds
            raise typer.BadParameter(str(exc), param_hint="--layouts") from None
        result["fresh"] = {"cae": reconstruction_figures(predict(model, fresh), fresh),
                           **baseline_figures(other, fresh)}
    if as_json:
        typer.echo(json.dumps(result))
        return
    typer.echo(f"{path}: grid {card['grid'][0]}x{card['grid'][1]}, d = {card['embedding']}, "
               f"walls {card['env']['walls']}")
    typer.echo("held-out (card):")
    typer.echo(table(result["card"]))
    if "fresh" in result:
        typer.echo(f"{layouts} fresh layouts (seed {seed}):")
        typer.echo(table(result["fresh"]))
