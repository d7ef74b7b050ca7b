"""``drlaas requester ...``: your requester record on the UMC."""

from __future__ import annotations

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


@requester_app.command("register")
def requester_register(
    key: KeyOpt, gateway: GatewayOpt = DEFAULT_GATEWAY, as_json: JsonOpt = False
) -> None:
    """Register the key's address as a requester (UMC.addRequester); an empty key on the
    embedded demo chain is funded from the faucet first."""
    with connect_funded(gateway, key) as gw:
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
