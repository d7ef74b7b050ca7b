"""``drlaas worker ...``: your worker record (register, status) and the daemon itself (run)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from drlaas.commands.client.models import shared_line
from drlaas.commands.client.session import (
    DEFAULT_GATEWAY,
    GatewayOpt,
    JsonOpt,
    KeyOpt,
    OwnKeyOpt,
    connect,
    connect_funded,
    emit,
    fail,
    kv,
    write,
)
from drlaas.commands.client.txcheck import expect_request, share_model_expect
from workers.daemon.capabilities import measure
from workers.daemon.command import (
    MAX_WORKER_DOMAINS,
    domains_option,
    open_worker,
    worker_command,
)
from workers.daemon.gateway import GatewayError
from workers.daemon.keys import load_key
from workers.daemon.links import default_worker_dir

worker_app = typer.Typer(
    help="Your worker: register, status, run (the daemon), share (an outcome as a model).",
    no_args_is_help=True,
)


@worker_app.command("register")
def worker_register(
    key: KeyOpt,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    domains: Annotated[
        str, typer.Option(help=f"domain codes (up to {MAX_WORKER_DOMAINS}), e.g. '0,3'")
    ] = "0",
    as_json: JsonOpt = False,
) -> None:
    """Register (or update) your worker record with this machine's measured capabilities."""
    served = domains_option(domains)
    caps = measure()
    body = {"domains": list(served), **caps.to_dict()}
    with connect_funded(gateway, key, create=True) as gw:
        try:
            out = write(  # UMC.addWorker, or updateCapabilities, with these capabilities
                gw,
                "POST",
                "/users/workers",
                body,
                expect=expect_request("POST", "/users/workers", body, gw.address),
            )
        except GatewayError as exc:
            fail(exc)
    emit(
        out,
        as_json,
        lambda d: typer.echo(
            f"worker {gw.address}: {'registered' if d.get('created', True) else 'updated'} "
            f"({caps.cpu_cores} cores, {caps.ram_gb} GB, GPU {caps.gpu_series})"
        ),
    )


@worker_app.command("status")
def worker_status(
    address: Annotated[str | None, typer.Argument(help="worker address (default: --key's)")] = None,
    key: Annotated[Path | None, typer.Option("--key", envvar="DRLAAS_KEY")] = None,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """A worker's status, capabilities, reputation and counters."""
    with connect(gateway, key) as gw:
        who = address or (gw.address if key else None)
        if who is None:
            fail(ValueError("give an ADDRESS or --key"))
        try:
            out = gw.get(f"/workers/{who}")
        except GatewayError as exc:
            fail(exc)
    emit(
        out,
        as_json,
        lambda d: typer.echo(kv(d, [k for k in d if not isinstance(d[k], dict | list)])),
    )


worker_app.command(
    "run",
    help="Run the worker daemon: register on chain, then accept, train and submit offered tasks.",
)(worker_command)


@worker_app.command("share")
def worker_share(
    task_id: int,
    key: OwnKeyOpt,
    description: str = "",
    data: Annotated[
        Path | None,
        typer.Option(help="the worker's directory, if `worker run` was given --data (default "
                     "<DRLAAS_DATA_DIR or ~/.drlaas>/workers/<address>, as `worker run`)"),
    ] = None,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Share your submitted outcome of TASK_ID as a model (MMC.addModel, once its requester
    accepted it): uploads the model's files from the daemon's job directory first, so an
    outcome sealed to its requester becomes public now."""
    try:
        check_worker_dir(data if data is not None else default_worker_dir(load_key(key).address),
                         given=data is not None)
        handler = open_worker(key, gateway, data)
        model = handler.publish_outcome(task_id)
    except Exception as exc:  # noqa: BLE001 - shown to the user with its type
        fail(exc)
    body = {
        "cid": model["cid"],
        "env": model["env"],
        "domain": model["domain"],
        "description": description or f"outcome of task {task_id}",
    }
    with connect_funded(gateway, key) as gw:
        try:
            out = write(
                gw, "POST", "/models", body, expect=share_model_expect("worker share", body, gw)
            )
        except GatewayError as exc:
            fail(exc)
    emit(out, as_json, lambda d: typer.echo(shared_line(d, model["cid"])))


def check_worker_dir(worker_dir: Path, *, given: bool) -> None:
    """FileNotFoundError naming ``worker_dir`` and how to name another when it holds no worker's
    jobs (nothing is opened there: a worker's pin file would be written into it)."""
    if (worker_dir / "jobs").is_dir():
        return
    how = ("give the folder `worker run --data` was given" if given else
           "give --data DIR if `worker run` was given --data DIR, or set DRLAAS_DATA_DIR as it "
           "was for `worker run` (a worker of `drlaas up` keeps its files in "
           "<up's data>/workers/<address>)")
    raise FileNotFoundError(f"no worker's jobs in {worker_dir}: {how}")
