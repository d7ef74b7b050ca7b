"""``drlaas deploy ...``: from one machine to a consortium (README, "From one machine to many").

* ``init``: validator keys, QBFT genesis and peer list (:mod:`backend.chain.consortium`);
* ``contracts``: the one-shot deploy job (:mod:`backend.chain.deployment`);
* ``worker``: start a worker daemon on a worker key no other container holds, so
  ``docker-compose up --scale worker=N`` gives N workers with N identities.
"""

from __future__ import annotations

import fcntl
import os
import re
import sys
from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer(help="Consortium deployment: genesis and keys, contract deployment, workers.")


@app.command("init")
def init_command(
    out: Annotated[Path, typer.Option(help="directory for keys and public files")] = Path(
        "deploy/consortium"
    ),
    validators: Annotated[
        int, typer.Option(min=1, help="validator nodes (4 tolerate 1 fault)")
    ] = 4,
    workers: Annotated[int, typer.Option(min=0, help="worker keys to create")] = 2,
    chain_id: Annotated[int, typer.Option(min=1, help="chain id of the consortium")] = 2025,
    hosts: Annotated[
        str, typer.Option(help="validators' hosts as peers reach them, comma-separated")
    ] = "",
    block_period: Annotated[int, typer.Option(min=1, help="seconds between blocks")] = 2,
) -> None:
    """Generate validator keys, the QBFT genesis and the validators' peer list."""
    from backend.chain.consortium import Layout, generate

    try:
        nodes = generate(
            out,
            validators=validators,
            workers=workers,
            chain_id=chain_id,
            hosts=[h.strip() for h in hosts.split(",") if h.strip()] or None,
            block_period=block_period,
        )
    except (ValueError, FileExistsError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    layout = Layout(out)
    typer.echo(f"genesis  {layout.genesis} (chain id {chain_id})")
    for n in nodes:
        typer.echo(f"{n.name:10s} {n.address}  {n.key_file}")
    typer.echo(f"deployer {layout.deployer_key}; worker keys in {layout.worker_keys}")
    typer.echo("keys are 0600 and must never be committed or copied to another member")


@app.command("worker-keys")
def worker_keys_command(
    count: Annotated[int, typer.Option(min=1, help="worker keys wanted in total")],
    out: Annotated[Path, typer.Option(help="directory given to `init`")] = Path(
        "deploy/consortium"
    ),
) -> None:
    """Create the missing worker keys up to COUNT (before scaling workers up)."""
    from backend.chain.consortium import Layout, add_worker_keys

    created = add_worker_keys(out, count)
    typer.echo(f"{len(created)} new worker keys; {count} in {Layout(out).worker_keys}")


@app.command("contracts")
def contracts_command(
    key: Annotated[Path, typer.Option("--key", help="deployer key file (funded in genesis)")],
    rpc: Annotated[
        str, typer.Option(envvar="DRLAAS_CHAIN", help="JSON-RPC URL of a validator")
    ] = "http://127.0.0.1:8545",
    out: Annotated[
        Path, typer.Option(envvar="DRLAAS_CONTRACTS", help="where to write contracts.json")
    ] = Path("deploy/consortium/public/contracts.json"),
    min_block: Annotated[
        int, typer.Option(min=0, help="wait until the chain has made this block")
    ] = 1,
    timeout: Annotated[float, typer.Option(min=1, help="seconds to wait for the chain")] = 600,
    cpu_workers: Annotated[
        bool, typer.Option("--cpu-workers", help="accept workers without a GPU (GPU series 0)")
    ] = False,
) -> None:
    """Wait for the chain, deploy UMC/TMC/MMC once and write contracts.json."""
    from backend.chain.deployment import deploy_to_file
    from backend.chain.platform import ALL_GPUS_BUT_NONE

    gpus = ALL_GPUS_BUT_NONE | 1 if cpu_workers else ALL_GPUS_BUT_NONE
    try:
        doc, deployed = deploy_to_file(
            rpc,
            key,
            out,
            min_block=min_block,
            timeout=timeout,
            accepted_gpus=gpus,
            on_wait=lambda why: typer.echo(
                f"waiting for the chain at {rpc} to reach block {min_block} ({why})", err=True
            ),
        )
    except (TimeoutError, FileNotFoundError, ValueError, ConnectionError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    verb = "deployed" if deployed else "already deployed"
    typer.echo(
        f"{verb} at block {doc['deploy_block']} on chain {doc['chain_id']}: "
        f"UMC {doc['UsersManager']}, TMC {doc['TasksManager']}, MMC {doc['ModelsManager']} "
        f"-> {out}"
    )


def _key_number(path: Path) -> int:
    m = re.search(r"(\d+)", path.stem)
    return int(m.group(1)) if m else 0


def claim_key(keys: Path) -> tuple[Path, int]:
    """A worker key in ``keys`` no other process holds, and the descriptor holding it.

    The claim is an exclusive ``flock`` on the key file: it lasts as long as the descriptor
    is open (through ``exec``), and ends by itself when the container stops."""
    paths = sorted(keys.glob("worker-*.key"), key=_key_number)
    for path in paths:
        fd = os.open(path, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            continue
        return path, fd
    raise RuntimeError(
        f"all {len(paths)} worker keys in {keys} are in use: create more with "
        f"`drlaas deploy worker-keys --count N` or scale down"
    )


@app.command(
    "worker",
    context_settings={"allow_extra_args": True, "ignore_unknown_options": True},
)
def worker_command(
    ctx: typer.Context,
    keys: Annotated[Path, typer.Option(help="directory of worker-<i>.key files")] = Path("/keys"),
) -> None:
    """Claim a free worker key and exec `drlaas worker run --key KEY ARGS...`."""
    try:
        path, fd = claim_key(keys)
    except RuntimeError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    os.set_inheritable(fd, True)  # the exec'd daemon keeps the claim
    typer.echo(f"worker key {path}", err=True)
    argv = [sys.executable, "-m", "drlaas.cli", "worker", "run", "--key", str(path), *ctx.args]
    os.execv(sys.executable, argv)
