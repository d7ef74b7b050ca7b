"""``drlaas requester ...``: your requester record on the UMC."""

from __future__ import annotations

from pathlib import Path

import typer

from drlaas.commands.client.session import (
    DEFAULT_GATEWAY,
    GatewayOpt,
    JsonOpt,
    KeyOpt,
    connect_funded,
    emit,
    fail,
    write,
)
from drlaas.commands.client.txcheck import UMC, Call, Expect
from workers.daemon.gateway import GatewayError

requester_app = typer.Typer(help="Your requester record.", no_args_is_help=True)

NOT_REQUESTER_RULES = ("tasks_not_requester", "models_not_requester")
"""The gateway's refusals of an address that is no registered requester (its own check and
the TMC's and MMC's reverts): their message names the REST route, a CLI user needs the command."""


def fail_with_register_hint(exc: Exception, key: Path) -> None:
    """Exit 1 with ``exc``, followed by the command that registers ``key`` when the gateway
    refused it for not being a registered requester."""
    detail = exc.detail if isinstance(exc, GatewayError) else None
    if isinstance(detail, dict) and detail.get("rule") in NOT_REQUESTER_RULES:
        typer.echo(f"error: {exc}\nrun: drlaas requester register --key {key}", err=True)
        raise typer.Exit(1)
    fail(exc)


@requester_app.command("register")
def requester_register(
    key: KeyOpt, gateway: GatewayOpt = DEFAULT_GATEWAY, as_json: JsonOpt = False
) -> None:
    """Register the key's address as a requester (UMC.addRequester); an empty key on the
    embedded demo chain is funded from the faucet first."""
    with connect_funded(gateway, key, create=True) as gw:
        try:
            out = write(
                gw,
                "POST",
                "/users/requesters",
                expect=Expect("requester register", (Call(UMC, "addRequester"),)),
            )
        except GatewayError as exc:
            fail(exc)
        emit(out, as_json, lambda d: typer.echo(_registered(gw.address, d.get("status"))))


def _registered(address: str, status: str | None) -> str:
    if status == "pending":
        return (f"requester {address} registered, pending a consortium admin's approval "
                "(until then it cannot post tasks)")
    return f"requester {address} registered"
