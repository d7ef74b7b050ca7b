"""The REST client CLI: ``drlaas task|model|worker|requester ...`` against a gateway.

Each command signs in with a local key file (EIP-4361 nonce, personal_sign, bearer token) when
it acts for an address. Writes the gateway cannot sign itself come back as 409
``sign_locally`` with the unsigned transaction: the CLI signs it with the key file and relays
it through ``POST /api/tx`` (docs/platform.md, "Signing"). Output is a readable table, or one
JSON document with ``--json``.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated, Any

import typer

from workers.daemon.gateway import Gateway, GatewayError

DEFAULT_GATEWAY = "http://127.0.0.1:8000"

GatewayOpt = Annotated[str, typer.Option("--gateway", envvar="DRLAAS_GATEWAY", help="gateway URL")]
KeyOpt = Annotated[
    Path, typer.Option("--key", envvar="DRLAAS_KEY", help="your key file (created if missing)")
]
JsonOpt = Annotated[bool, typer.Option("--json", help="print one JSON document")]

task_app = typer.Typer(help="Training tasks: submit, list, show, review.", no_args_is_help=True)
model_app = typer.Typer(help="Shared models: list, show, pull, share.", no_args_is_help=True)
worker_app = typer.Typer(help="Your worker record: register, status.", no_args_is_help=True)
requester_app = typer.Typer(help="Your requester record.", no_args_is_help=True)


# -- helpers ----------------------------------------------------------------------------------
def connect(gateway: str, key: Path | None = None) -> Gateway:
    account = None
    if key is not None:
        from workers.daemon.keys import load_or_create_key

        account = load_or_create_key(key)
    return Gateway(gateway or os.environ.get("DRLAAS_GATEWAY", DEFAULT_GATEWAY), account)


def write(gw: Gateway, method: str, path: str, body: Any = None) -> Any:
    """A write acting as the key's address: relay the transaction ourselves if the gateway
    answers ``sign_locally`` (it holds no key for us)."""
    try:
        return gw.request(method, path, json=body, auth=True)
    except GatewayError as exc:
        detail = exc.detail if isinstance(exc.detail, dict) else {}
        if exc.status != 409 or detail.get("rule") != "sign_locally" or "tx" not in detail:
            raise
        tx = {
            k: (int(v, 16) if isinstance(v, str) and k in _INT_FIELDS and v.startswith("0x") else v)
            for k, v in detail["tx"].items()
        }
        assert gw.account is not None
        raw = "0x" + bytes(gw.account.sign_transaction(tx).raw_transaction).hex()
        try:
            return gw.post("/tx", {"raw": raw}, auth=True)
        except GatewayError as relay_exc:
            rule = relay_exc.detail.get("rule") if isinstance(relay_exc.detail, dict) else None
            if relay_exc.status != 422 or rule != "tx_invalid":
                raise
            # the relay could not decode a valid signed transaction: send it to the chain's
            # JSON-RPC endpoint ourselves (platform.md: clients may send raw transactions)
            return send_raw(gw.url + "/rpc", raw)


def send_raw(rpc_url: str, raw: str, timeout: float = 60.0) -> dict[str, Any]:
    """eth_sendRawTransaction at ``rpc_url`` and wait for the receipt; error if it reverted."""
    from web3 import Web3

    w3 = Web3(Web3.HTTPProvider(rpc_url, request_kwargs={"timeout": timeout}))
    tx_hash = w3.eth.send_raw_transaction(bytes.fromhex(raw.removeprefix("0x")))
    receipt = w3.eth.wait_for_transaction_receipt(tx_hash, timeout=timeout)
    if receipt["status"] != 1:
        raise RuntimeError(f"transaction 0x{bytes(tx_hash).hex()} reverted")
    return {
        "tx_hash": "0x" + bytes(tx_hash).hex(),
        "block_number": receipt["blockNumber"],
        "status": receipt["status"],
        "events": [],
    }


_INT_FIELDS = {
    "value",
    "nonce",
    "chainId",
    "gas",
    "maxFeePerGas",
    "maxPriorityFeePerGas",
    "gasPrice",
    "type",
}


def fail(exc: Exception) -> None:
    typer.echo(f"error: {exc}", err=True)
    raise typer.Exit(1)


def read(gateway: str, path: str, params: dict[str, Any] | None = None) -> Any:
    """GET ``path`` from the gateway (no sign-in needed); exit with the error on failure."""
    with connect(gateway) as gw:
        try:
            return gw.get(path, params=params) if params else gw.get(path)
        except GatewayError as exc:
            fail(exc)


def emit(doc: Any, as_json: bool, render: Any = None) -> None:
    if as_json or render is None:
        typer.echo(json.dumps(doc, indent=1, sort_keys=True, default=str))
    else:
        render(doc)


def table(rows: list[dict[str, Any]], columns: list[tuple[str, str]]) -> str:
    """A plain fixed-width table of ``rows`` with (key, header) ``columns``."""

    def cell(v: Any) -> str:
        if v is None:
            return "-"
        if isinstance(v, float):
            return f"{v:.3f}"
        s = str(v)
        return s if len(s) <= 46 else s[:20] + "…" + s[-20:]

    cells = [[cell(r.get(k)) for k, _ in columns] for r in rows]
    widths = [max([len(h)] + [len(c[i]) for c in cells]) for i, (_, h) in enumerate(columns)]
    lines = ["  ".join(h.ljust(w) for (_, h), w in zip(columns, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in cells]
    return "\n".join(lines)


def kv(doc: dict[str, Any], keys: list[str]) -> str:
    width = max(len(k) for k in keys)
    return "\n".join(f"{k.ljust(width)}  {doc.get(k, '-')}" for k in keys)


# -- requester ----------------------------------------------------------------------------------
@requester_app.command("register")
def requester_register(
    key: KeyOpt, gateway: GatewayOpt = DEFAULT_GATEWAY, as_json: JsonOpt = False
) -> None:
    """Register the key's address as a requester (UMC.addRequester)."""
    with connect(gateway, key) as gw:
        try:
            out = write(gw, "POST", "/users/requesters")
        except GatewayError as exc:
            fail(exc)
        emit(out, as_json, lambda d: typer.echo(f"requester {gw.address} registered"))


# -- tasks ----------------------------------------------------------------------------------
def task_body(
    *,
    grid: str,
    agents: int,
    walls: str,
    kind: str,
    window: int,
    steps: int,
    minutes: int,
    seed: int,
    workers: int,
    payment_wei: int,
    deadline_s: int,
    domain: int,
    spec: Path | None,
) -> dict[str, Any]:
    """POST /tasks body from options, or from a JSON file (``--spec``) that options fill in.
    The spec part is checked locally with the core's TrainingSpec (the gateway's own parser)."""
    from workers.mdrl.spec import parse_grid, parse_walls
    from workers.mdrl.trainingspec import SpecError, TrainingSpec

    if spec is not None:
        return json.loads(spec.read_text())
    rows, cols = parse_grid(grid)
    doc = {
        "env": {"rows": rows, "cols": cols, "agents": agents, "walls": list(parse_walls(walls))},
        "observation": {"kind": kind, "window": window},
        "budget": {"steps": steps, "minutes": minutes},
        "seed": seed,
    }
    try:
        TrainingSpec.from_dict(doc)
    except SpecError as exc:
        raise typer.BadParameter(exc.msg, param_hint=exc.field) from None
    return {
        **doc,
        "num_workers": workers,
        "payment_wei": payment_wei,
        "deadline_s": deadline_s,
        "domain": domain,
    }


@task_app.command("submit")
def task_submit(
    key: KeyOpt,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    grid: Annotated[str, typer.Option(help="ROWSxCOLS")] = "10x10",
    agents: Annotated[int, typer.Option(min=1)] = 3,
    walls: Annotated[str, typer.Option(help="count or range, e.g. 0-2")] = "0",
    kind: Annotated[str, typer.Option(help="odmtl | dmtl | cmtl")] = "odmtl",
    window: Annotated[int, typer.Option(help="ODMTL window (odd)")] = 3,
    steps: Annotated[int, typer.Option(help="env-step budget")] = 200_000,
    minutes: Annotated[int, typer.Option(help="wall-clock cap")] = 30,
    seed: int = 0,
    workers: Annotated[int, typer.Option(min=1, help="workers to recruit")] = 1,
    payment_wei: Annotated[int, typer.Option(min=0, help="reward per worker (escrowed)")] = 0,
    deadline_s: Annotated[int, typer.Option(min=60)] = 86_400,
    domain: int = 0,
    spec: Annotated[Path | None, typer.Option(help="JSON body of POST /api/tasks instead")] = None,
    as_json: JsonOpt = False,
) -> None:
    """Submit a training task: the spec goes to the content store, the chain recruits."""
    body = task_body(
        grid=grid,
        agents=agents,
        walls=walls,
        kind=kind,
        window=window,
        steps=steps,
        minutes=minutes,
        seed=seed,
        workers=workers,
        payment_wei=payment_wei,
        deadline_s=deadline_s,
        domain=domain,
        spec=spec,
    )
    with connect(gateway, key) as gw:
        try:
            out = write(gw, "POST", "/tasks", body)
        except GatewayError as exc:
            fail(exc)
        emit(
            out,
            as_json,
            lambda d: typer.echo(
                f"task {d['task_id']} submitted (spec {d['spec_cid']}); offered to: "
                + (", ".join(d.get("offered") or []) or "nobody yet")
            ),
        )


@task_app.command("list")
def task_list(
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    status: Annotated[str | None, typer.Option(help="open|completed|cancelled|closed")] = None,
    requester: str | None = None,
    worker: str | None = None,
    as_json: JsonOpt = False,
) -> None:
    """List tasks (filter by status, requester, worker)."""
    params = {
        k: v for k, v in {"status": status, "requester": requester, "worker": worker}.items() if v
    }
    out = read(gateway, "/tasks", params=params)
    emit(
        out,
        as_json,
        lambda d: typer.echo(
            table(
                d["data"],
                [
                    ("id", "ID"),
                    ("status", "STATUS"),
                    ("requester", "REQUESTER"),
                    ("num_workers", "WORKERS"),
                    ("offered", "OFFERED"),
                    ("deadline", "DEADLINE"),
                    ("description", "SPEC CID"),
                ],
            )
        ),
    )


@task_app.command("show")
def task_show(
    task_id: int, gateway: GatewayOpt = DEFAULT_GATEWAY, as_json: JsonOpt = False
) -> None:
    """A task with its offers, outcomes and the live training curve."""
    out = read(gateway, f"/tasks/{task_id}")

    def render(d: dict[str, Any]) -> None:
        typer.echo(kv(d, ["id", "status", "requester", "num_workers", "deadline", "description"]))
        if d.get("offers"):
            typer.echo(
                "\noffers\n"
                + table(d["offers"], [("worker", "WORKER"), ("state", "STATE"), ("qos", "QOS")])
            )
        if d.get("outcomes"):
            typer.echo(
                "\noutcomes\n"
                + table(d["outcomes"], [("worker", "WORKER"), ("cid", "CID"), ("review", "REVIEW")])
            )
        if d.get("progress"):
            typer.echo(
                "\nprogress\n"
                + table(
                    d["progress"][-10:],
                    [
                        ("worker", "WORKER"),
                        ("step", "STEP"),
                        ("success", "SUCCESS"),
                        ("time", "TIME"),
                        ("cost", "COST"),
                    ],
                )
            )

    emit(out, as_json, render)


@task_app.command("review")
def task_review(
    task_id: int,
    worker: Annotated[str, typer.Option(help="worker whose outcome you review")],
    review: Annotated[int, typer.Option(min=0, max=5, help="0-5")],
    key: KeyOpt,
    reject: Annotated[bool, typer.Option(help="reject the outcome (no payment)")] = False,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Review a worker's outcome (TMC.reviewOutcome): pays and updates its reputation."""
    with connect(gateway, key) as gw:
        try:
            out = write(
                gw,
                "POST",
                f"/tasks/{task_id}/reviews",
                {"worker": worker, "review": review, "accepted": not reject},
            )
        except GatewayError as exc:
            fail(exc)
    emit(out, as_json, lambda d: typer.echo(f"reviewed {worker} on task {task_id}: {review}/5"))


# -- models ----------------------------------------------------------------------------------
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
        card = d.get("card") or {}
        if card:
            typer.echo(
                f"\nmodel {card.get('model')} for {card.get('env', {}).get('agents')} agents "
                f"on {card.get('env', {}).get('rows')}x{card.get('env', {}).get('cols')}; "
                f"metrics: {json.dumps(card.get('metrics', {}))[:200]}"
            )

    emit(out, as_json, render)


@model_app.command("pull")
def model_pull(
    model: Annotated[str, typer.Argument(help="model id or manifest CID")],
    out: Annotated[Path, typer.Option("--out", help="directory to write the model into")] = Path(
        "model"
    ),
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Fetch a model's manifest and files, each verified against its CID.

    Reads the content store of DRLAAS_IPFS when it is reachable from here (embedded store on
    this machine, or an IPFS node); the gateway resolves a model id to its CID."""
    from backend.settings import load_settings
    from backend.store.bundle import pull_model
    from workers.daemon.links import open_store

    cid = model
    if model.isdigit():
        with connect(gateway) as gw:
            try:
                cid = gw.get(f"/models/{model}")["cid"]
            except GatewayError as exc:
                fail(exc)
    try:
        with open_store(load_settings()) as store:
            path = pull_model(store, cid, out)
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
    with connect(gateway, key) as gw:
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


# -- worker ----------------------------------------------------------------------------------
@worker_app.command("register")
def worker_register(
    key: KeyOpt,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    domains: Annotated[str, typer.Option(help="domain codes, e.g. '0,3' or 'all'")] = "0",
    as_json: JsonOpt = False,
) -> None:
    """Register (or update) your worker record with this machine's measured capabilities."""
    from workers.daemon.capabilities import measure
    from workers.daemon.command import parse_domains

    caps = measure()
    with connect(gateway, key) as gw:
        try:
            out = write(
                gw,
                "POST",
                "/users/workers",
                {"domains": list(parse_domains(domains)), **caps.to_dict()},
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


from workers.daemon.command import worker_command  # noqa: E402 - the daemon itself

worker_app.command(
    "run",
    help="Run the worker daemon: register on chain, then accept, train and submit offered tasks.",
)(worker_command)
