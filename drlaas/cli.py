"""The ``drlaas`` command: one entry point over the MDRL core and the platform.

``train`` and ``eval`` need only the MDRL core (a laptop is enough); ``up``, ``task``,
``model``, ``worker`` and ``requester`` drive the platform; ``chain`` deploys the contracts on
an embedded EVM.
"""

from __future__ import annotations

import os
import sys

import httpx
import typer
from typer.core import TyperGroup

from backend.chain.client import NodeRefused
from backend.chain.commands import app as chain_app
from backend.chain.pyevm import restore_recursion_limit
from drlaas.commands.client import model_app, requester_app, task_app, worker_app
from drlaas.commands.client.models import fetch_model
from drlaas.commands.client.pins import pin_app
from drlaas.commands.deploy import app as deploy_app
from drlaas.commands.scenario import scenario_command
from drlaas.commands.up import up_command
from workers.daemon.links import SetupError
from workers.mdrl.commands import train as train_command
from workers.mdrl.commands.cae import app as cae_app
from workers.mdrl.commands.evaluate import eval_command
from workers.mdrl.commands.train import train
from workers.mdrl.commands.zoo import app as zoo_app

# web3 (through py_ecc) raised the interpreter's recursion limit to 100,000 on import: a
# deeply nested JSON card or config then overflowed the C stack (a segfault) where the parsers'
# RecursionError guards expect the normal limit. Every command runs after this line.
restore_recursion_limit()



class DrlaasGroup(TyperGroup):
    """Every command: a platform that cannot be reached, or settings it cannot start with, end
    the command with one line saying what to do, not with a traceback."""

    def invoke(self, ctx: typer.Context) -> object:
        try:
            return super().invoke(ctx)
        except httpx.TransportError as exc:
            try:
                where = str(exc.request.url.copy_with(query=None))
            except RuntimeError:  # no request attached
                where = "the platform"
            typer.echo(
                f"error: cannot reach {where} ({exc or type(exc).__name__}): is the platform "
                f"running (`drlaas up`), and is --gateway / DRLAAS_GATEWAY its URL?",
                err=True,
            )
            raise typer.Exit(1) from None
        except BrokenPipeError:  # `drlaas ... | head`: the reader left, nothing to report
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())  # the interpreter's final flush fails quietly
            raise typer.Exit(0) from None
        except (SetupError, NodeRefused, ConnectionError) as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(1) from None


app = typer.Typer(
    cls=DrlaasGroup,
    name="drlaas",
    help="DRL as a Service: train, evaluate and share multi-agent RL models.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
)
train_command.MODEL_FETCHER = fetch_model  # experts / walls CAEs by CID, through the gateway
app.command("train", help="Train an MDRL model (PPO: CMTL / DMTL / ODMTL).")(train)
app.command("eval", help="Evaluate a model or a baseline against the oracle.")(eval_command)
app.add_typer(zoo_app, name="zoo")  # list | train: the shipped models of models/
app.add_typer(cae_app, name="cae")  # train | eval: the Ch. 4 walls autoencoder

app.add_typer(task_app, name="task")
app.add_typer(model_app, name="model")
app.add_typer(worker_app, name="worker")  # register | status | run (the daemon)
app.add_typer(requester_app, name="requester")
app.add_typer(pin_app, name="pin")  # show | forget: deployments pinned on first use
app.command("up", help="Start the whole platform embedded here (Ctrl-C stops it).")(up_command)
app.command("demo-scenario", help="Run the end-to-end scenario (register, submit, train, review, "
            "share) against a running `drlaas up`; `make demo` starts one and runs it.")(
    scenario_command
)

app.add_typer(chain_app, name="chain")
app.add_typer(deploy_app, name="deploy")  # consortium: genesis, contracts, workers


if __name__ == "__main__":
    app()
