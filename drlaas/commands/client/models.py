"""``drlaas model ...``: shared models: list, show, pull (through the gateway, CID-verified),
share."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Annotated, Any

import typer

from backend.store.bundle import pull_model
from backend.store.gateway_blocks import GatewayBlocks
from drlaas.commands.client.session import (
    DEFAULT_GATEWAY,
    GatewayOpt,
    JsonOpt,
    KeyOpt,
    connect_funded,
    emit,
    fail,
    kv,
    read,
    table,
    write,
)
from workers.daemon.gateway import GatewayError

model_app = typer.Typer(help="Shared models: list, show, pull, share.", no_args_is_help=True)


def pull(gateway: str, cid: str, out: Path) -> Path:
    """Both files of model bundle ``cid`` into ``out``, fetched block by block through the
    gateway and each block verified against its CID here."""
    with GatewayBlocks(gateway) as store:
        return pull_model(store, cid, out)


def default_out(name: str) -> Path:
    """Where ``pull`` writes without ``--out``: ``./model-<id or CID>`` in this directory."""
    return Path(f"model-{re.sub(r'[^A-Za-z0-9]', '', name)[:64]}")


@model_app.command("list")
def model_list(
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    domain: int | None = None,
    agents: int | None = None,
    walls: int | None = None,
    min_reputation: float | None = None,
    q: Annotated[str | None, typer.Option(help="text search")] = None,
    as_json: JsonOpt = False,
) -> None:
    """List shared models (filter by domain, team size, walls, reputation)."""
    params = {
        k: v
        for k, v in {
            "domain": domain,
            "agents": agents,
            "walls": walls,
            "min_reputation": min_reputation,
            "q": q,
        }.items()
        if v is not None
    }
    out = read(gateway, "/models", params=params)
    emit(
        out,
        as_json,
        lambda d: typer.echo(
            table(
                d["data"],
                [
                    ("id", "ID"),
                    ("owner", "OWNER"),
                    ("domain", "DOMAIN"),
                    ("agents", "AGENTS"),
                    ("reputation", "REPUTATION"),
                    ("allocations", "ALLOCS"),
                    ("cid", "CID"),
                ],
            )
        ),
    )


@model_app.command("show")
def model_show(
    model_id: int, gateway: GatewayOpt = DEFAULT_GATEWAY, as_json: JsonOpt = False
) -> None:
    """A model: card, metrics, owner reputation, CID."""
    out = read(gateway, f"/models/{model_id}")

    def render(d: dict[str, Any]) -> None:
        typer.echo(
            kv(
                d,
                [
                    "id",
                    "cid",
                    "owner",
                    "domain",
                    "env",
                    "reputation",
                    "owner_reputation",
                    "allocations",
                    "description",
                ],
            )
        )
        lines = hub_lines(d)
        if lines:
            typer.echo("\n" + "\n".join(lines))

    emit(out, as_json, render)


def hub_lines(d: dict[str, Any]) -> list[str]:
    """The model page's figures as text (GET /models/{id}: provenance, held-out, curve)."""
    lines = []
    if d.get("name") or d.get("kind"):
        lines.append(" ".join(str(x) for x in (d.get("name"), d.get("kind")) if x))
    p = d.get("produced_by")
    lines.append(
        f"produced by task {p['task_id']} (worker {p['worker']}; the chain's outcome record)"
        if p
        else "an owner's upload (no task's outcome)"
    )
    for x in d.get("experts") or []:
        where = f"model {x['model_id']}" if x.get("model_id") else "not listed here"
        lines.append(f"expert {x['ref']} ({where}; from the {x['source'].replace('_', ' ')})")
    held = d.get("heldout")
    for f in (held or {}).get("readings", []):
        time = "-" if f.get("time") is None else f"{f['time']:.2f}"
        oracle = "-" if f.get("oracle_time") is None else f"{f['oracle_time']:.2f}"
        lines.append(
            f"held-out ({held['episodes']} episodes, {f['reading_model']} readings): "
            f"success {100 * f['success']:.1f}%, time {time} (oracle {oracle}), "
            f"cost {'-' if f.get('cost') is None else format(f['cost'], '.2f')}"
        )
    curve = d.get("curve") or []
    if curve:
        last = curve[-1]
        lines.append(
            f"curve: {len(curve)} points to {last['step']} env steps; last success "
            f"{last.get('success')}, time {last.get('time')}, cost {last.get('cost')}"
        )
    return lines


@model_app.command("pull")
def model_pull(
    model: Annotated[str, typer.Argument(help="model id or manifest CID")],
    out: Annotated[
        Path | None,
        typer.Option("--out", help="directory to write the model into (default ./model-<MODEL>)"),
    ] = None,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Download a model (model.safetensors + model.json) through the gateway, every block
    verified against its CID; a model id is resolved to its CID by the gateway."""
    cid = model
    if model.isdigit():
        cid = read(gateway, f"/models/{model}")["cid"]
    dest = out if out is not None else default_out(model)
    try:
        path = pull(gateway, cid, dest)
    except Exception as exc:  # noqa: BLE001 - shown to the user with its type
        fail(RuntimeError(f"cannot pull {cid}: {type(exc).__name__}: {exc}"))
    emit({"cid": cid, "path": str(path)}, as_json, lambda d: typer.echo(f"model {cid} -> {path}"))


@model_app.command("share")
def model_share(
    cid: Annotated[str, typer.Option(help="manifest CID of the model")],
    key: KeyOpt,
    env_json: Annotated[
        str, typer.Option("--env", help="EnvSpec JSON the model was trained on")
    ] = "{}",
    description: str = "",
    domain: int = 0,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Share a model (MMC.addModel) so requesters can be allocated it."""
    with connect_funded(gateway, key) as gw:
        try:
            out = write(
                gw,
                "POST",
                "/models",
                {
                    "cid": cid,
                    "description": description,
                    "domain": domain,
                    "env": json.loads(env_json),
                },
            )
        except GatewayError as exc:
            fail(exc)
    emit(out, as_json, lambda d: typer.echo(f"model shared: {json.dumps(d)[:200]}"))
