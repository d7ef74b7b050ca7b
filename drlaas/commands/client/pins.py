"""``drlaas pin show|forget``: the deployments a key's CLI and its worker pinned on first use
(contracts and chain id per gateway URL, :mod:`backend.chain.pins`). After a real redeployment
at the same URL, ``forget`` lets the next use pin the new one, instead of editing JSON."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from backend.chain.pins import forget_pin, read_pins
from drlaas.commands.client.session import DEFAULT_GATEWAY, GatewayOpt, JsonOpt, fail
from drlaas.commands.client.txcheck import pin_file
from workers.daemon.keys import load_key
from workers.daemon.links import PIN_FILE, default_worker_dir

pin_app = typer.Typer(
    help="Deployments pinned on first use, per gateway URL: show, forget.", no_args_is_help=True
)

ExistingKey = Annotated[
    Path, typer.Option("--key", envvar="DRLAAS_KEY", exists=True, dir_okay=False,
                       help="the key file whose pins these are")
]
WorkerData = Annotated[
    Path | None, typer.Option("--data", help="the worker's directory, if `worker run` was "
                              "given --data (default <DRLAAS_DATA_DIR or ~/.drlaas>/workers/"
                              "<address>)")
]


def pin_files(key: Path, data: Path | None) -> dict[str, Path]:
    """{who: pin file}: the CLI's (``<key>.platform.json``) and the key's worker's."""
    worker_dir = data if data is not None else default_worker_dir(load_key(key).address)
    return {"cli": pin_file(key), "worker": worker_dir / PIN_FILE}


@pin_app.command("show")
def pin_show(key: ExistingKey, data: WorkerData = None, as_json: JsonOpt = False) -> None:
    """Print what is pinned for each gateway URL, by the CLI and by the key's worker."""
    try:
        doc = {who: {"file": str(path), "pins": read_pins(path)}
               for who, path in pin_files(key, data).items()}
    except ValueError as exc:
        fail(exc)
    if as_json:
        typer.echo(json.dumps(doc, indent=1, sort_keys=True))
        return
    for who, entry in doc.items():
        typer.echo(f"{who}: {entry['file']}" + ("" if entry["pins"] else " (nothing pinned)"))
        for url, pin in sorted(entry["pins"].items()):
            contracts = ", ".join(f"{n}={a}" for n, a in sorted(pin["contracts"].items()))
            typer.echo(f"  {url}: chain {pin['chain_id']}, {contracts}")


@pin_app.command("forget")
def pin_forget(
    key: ExistingKey, gateway: GatewayOpt = DEFAULT_GATEWAY, data: WorkerData = None
) -> None:
    """Forget the deployment pinned for the gateway URL (after the platform there was really
    redeployed): the CLI's and the key's worker's; the next use pins the new one."""
    url = gateway.rstrip("/")
    try:
        forgot = [who for who, path in pin_files(key, data).items() if forget_pin(path, url)]
    except ValueError as exc:
        fail(exc)
    if not forgot:
        typer.echo(f"nothing was pinned for {url} with {key}", err=True)
        return
    typer.echo(f"forgot the deployment pinned for {url} ({' and '.join(forgot)}); the next use "
               "pins the one it finds there")
