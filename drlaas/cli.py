"""The ``drlaas`` command: one entry point over the MDRL core and the platform.

``train`` and ``eval`` need only the MDRL core (a laptop is enough); ``chain`` deploys the
contracts on an embedded EVM. Platform commands import their modules lazily, so the core
commands never load web3.
"""

from __future__ import annotations

import typer

from workers.mdrl.commands.evaluate import eval_command
from workers.mdrl.commands.train import train

app = typer.Typer(
    name="drlaas",
    help="DRL as a Service: train, evaluate and share multi-agent RL models.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
app.command("train", help="Train an MDRL model (PPO; CMTL / DMTL / ODMTL) from a preset or config file.")(train)
app.command("eval", help="Evaluate a model or a baseline on seeded episodes against the oracle.")(eval_command)

chain_app = typer.Typer(help="Consortium-chain contracts (UMC, TMC, MMC).", no_args_is_help=True)
app.add_typer(chain_app, name="chain")


@chain_app.command("gas-report")
def gas_report(
    workers: int = typer.Option(50, "--workers", min=1, max=2000, help="Candidate workers for allocation gas."),
    json_out: bool = typer.Option(False, "--json", help="Print one JSON object on stdout."),
) -> None:
    """Deploy on the embedded chain, run every function, print gas per function."""
    from backend.chain.commands import gas_report_command

    gas_report_command(workers=workers, json_out=json_out)


if __name__ == "__main__":
    app()
