"""``drlaas task ...``: submit a training task, list, show, wait, pull, review, allocate,
cancel.

The body of ``POST /api/tasks`` is built in one place, :func:`task_body`. When the gateway holds
no key for the requester, ``submit`` relays the signed ``addTask`` itself and then allocates the
task the same way (``POST /api/tasks/{id}/allocate``, docs/platform.md "Signing").

Experts (MEDC, thesis Alg. 5.1): ``--experts CID,CID`` names them (``--expert-qos`` weighs
them), ``--experts-from-mmc K`` first buys K of them from the MMC (``allocateModel``, Eq. 10-13
/ 22-23; :func:`drlaas.commands.client.models.request_models`) and ``--expert-allocation ID``
uses an allocation made before; the gateway then writes the allocated CIDs and their QoS into
the spec.
"""

from __future__ import annotations

import datetime as dt
import json
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from backend.chain.platform import TaskStatus, cid_hash
from backend.schemas.common import wei_to_eth
from backend.store import CID, InvalidCID
from backend.store.gateway_blocks import GatewayBlocks
from backend.store.sealed import (
    SEALED_FILE,
    public_key_hex,
    pull_model_with_key,
    sealed_envelopes,
)
from drlaas.commands.client.models import ForceOpt, pull_into, request_models
from drlaas.commands.client.session import (
    DEFAULT_GATEWAY,
    CliGateway,
    GatewayOpt,
    JsonOpt,
    KeyOpt,
    OwnKeyOpt,
    connect,
    connect_funded,
    emit,
    event_arg,
    fail,
    kv,
    read,
    table,
    terminal_safe,
    terminal_text,
    write,
)
from drlaas.commands.client.txcheck import (
    TMC,
    Call,
    Expect,
    add_task_call,
    pinned_contract,
)
from drlaas.commands.client.users import fail_with_register_hint
from workers.daemon.gateway import Gateway, GatewayError
from workers.daemon.keys import load_key
from workers.mdrl.medc import parse_list
from workers.mdrl.spec import parse_grid, parse_walls
from workers.mdrl.specfields import check_object
from workers.mdrl.trainingspec import (
    DEMONSTRATION_RULES,
    MAX_SPEC_BYTES,
    SpecError,
    TrainingSpec,
)

task_app = typer.Typer(
    help="Training tasks: submit, list, show, wait, pull, review, allocate, cancel.",
    no_args_is_help=True,
)

NOT_INDEXED_GRACE_S = 30.0
"""How long ``task wait`` takes the gateway's 404 for "not indexed yet" (its indexer may lag a
few blocks behind a submit) before it says the task does not exist."""
HOLDING_STATES = ("accepted", "submitted")
"""Offer states in which a worker holds one of the task's slots."""


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
    experts: str | None = None,
    expert_qos: str | None = None,
    expert_rate: float | None = None,
    expert_threshold: float | None = None,
    expert_credit: bool = False,
    expert_rate_end: float | None = None,
    keep_best: str | None = None,
) -> dict[str, Any]:
    """POST /tasks body from options, or from a JSON file (``--spec``) that options fill in.
    The spec part is checked locally with the core's TrainingSpec (the gateway's own parser).
    ``experts``/``expert_qos`` are comma-separated CIDs and weights (``drlaas train``'s form)."""
    if spec is not None:
        return body_file(spec)
    try:
        rows, cols = parse_grid(grid)
    except ValueError as exc:  # "10x" ended the command with a traceback
        raise typer.BadParameter(str(exc), param_hint="--grid") from None
    try:
        wall_range = list(parse_walls(walls))
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--walls") from None
    doc: dict[str, Any] = {
        "env": {"rows": rows, "cols": cols, "agents": agents, "walls": wall_range},
        "observation": {"kind": kind, "window": window},
        "budget": {"steps": steps, "minutes": minutes},
        "seed": seed,
    }
    if keep_best is not None:
        doc["selection"] = {"keep_best": keep_best}
    if experts is not None:
        doc["experts"] = expert_list(experts, expert_qos)
    elif expert_qos is not None:
        raise typer.BadParameter("--expert-qos weighs --experts", param_hint="--expert-qos")
    demo = {
        "rate": expert_rate,
        "threshold": expert_threshold,
        "credit": expert_credit or None,
        "rate_end": expert_rate_end,
    }
    demo = {k: v for k, v in demo.items() if v is not None}
    try:
        TrainingSpec.from_dict(doc)
        if demo:  # checked on its own: the experts may come from the MMC, on the gateway
            doc["algorithm"] = {
                "demonstration": check_object(demo, DEMONSTRATION_RULES, "algorithm.demonstration")
            }
    except SpecError as exc:
        raise typer.BadParameter(exc.msg, param_hint=exc.field) from None
    return {
        **doc,
        "num_workers": workers,
        "payment_wei": payment_wei,
        "deadline_s": deadline_s,
        "domain": domain,
    }


def body_file(path: Path) -> dict[str, Any]:
    """The JSON object of ``--spec FILE``, read up to :data:`MAX_SPEC_BYTES` (a missing,
    endless, non-JSON or nested file ended the command with a traceback); a usage error
    naming the file otherwise."""
    try:
        with path.open("rb") as fh:
            raw = fh.read(MAX_SPEC_BYTES + 1)
        if len(raw) > MAX_SPEC_BYTES:
            raise ValueError(f"more than {MAX_SPEC_BYTES} bytes, the bound of a task spec")
        doc = json.loads(raw)
    except (OSError, ValueError, RecursionError) as exc:
        raise typer.BadParameter(f"{path}: {exc}", param_hint="--spec") from None
    if not isinstance(doc, dict):
        raise typer.BadParameter(
            f"{path}: the body of POST /api/tasks is a JSON object, not "
            f"{type(doc).__name__}", param_hint="--spec")
    for name in WHOLE_TERMS + FRACTION_TERMS:  # what the CLI reads itself (add_task_call)
        if name not in doc:
            continue
        v = doc[name]
        whole = type(v) is int and v >= 0
        fraction = type(v) in (int, float) and 0 <= v <= 1
        if not (whole if name in WHOLE_TERMS else fraction):
            what = "a whole number >= 0" if name in WHOLE_TERMS else "a number in 0-1"
            raise typer.BadParameter(
                f"{path}: {name} is {what}, not {json.dumps(v)[:40]}", param_hint="--spec")
    return doc


WHOLE_TERMS = ("num_workers", "payment_wei", "deadline_s", "domain", "min_cpu_cores",
               "min_ram_gb")
FRACTION_TERMS = ("min_reputation", "min_rating")
"""The terms of a ``--spec`` body the CLI reads to check the ``addTask`` it signs: a string
or null there ended ``task submit`` with a traceback after signing in."""
SPEC_OPTIONS = ("grid", "agents", "walls", "kind", "window", "steps", "minutes", "seed",
                "workers", "payment_wei", "deadline_s", "domain", "experts", "expert_qos",
                "expert_rate", "expert_rate_end", "expert_threshold", "expert_credit",
                "keep_best")
"""The options :func:`task_body` builds a body from, which ``--spec FILE`` replaces: given
with it, they were dropped silently (``--experts`` submitted a task without its experts)."""


def expert_list(experts: str, qos: str | None) -> list[Any]:
    """``--experts a,b [--expert-qos 0.7,0.3]`` -> the spec's ``experts``."""
    try:
        cids = parse_list(experts, "--experts")
        for c in cids:
            if str(CID.parse(c).v1()) != c:
                raise ValueError(f"--experts: give {c!r} in canonical form {CID.parse(c).v1()}")
        if qos is None:
            return list(cids)
        weights = [float(q) for q in parse_list(qos, "--expert-qos")]
    except InvalidCID as exc:
        raise typer.BadParameter(
            f"experts are model CIDs (`drlaas model list`): {exc}", param_hint="--experts"
        ) from None
    except ValueError as exc:
        raise typer.BadParameter(str(exc)) from None
    if len(weights) != len(cids):
        raise typer.BadParameter(
            f"{len(weights)} weight(s) for {len(cids)} expert(s)", param_hint="--expert-qos"
        )
    return [{"model": c, "qos": q} for c, q in zip(cids, weights, strict=True)]


@task_app.command("submit")
def task_submit(
    ctx: typer.Context,
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
    payment_wei: Annotated[
        int,
        typer.Option(
            min=0,
            help="reward per worker, escrowed (at least the consortium minimum per worker-hour "
            "of the deadline window; the gateway names it when too low)",
        ),
    ] = 10**16,
    deadline_s: Annotated[int, typer.Option(min=60)] = 86_400,
    domain: int = 0,
    spec: Annotated[Path | None, typer.Option(help="JSON body of POST /api/tasks instead")] = None,
    experts: Annotated[
        str | None,
        typer.Option(help="MEDC experts: model CIDs, comma-separated (see `drlaas model list`)"),
    ] = None,
    expert_qos: Annotated[
        str | None, typer.Option(help="QoS weight of each --experts model, comma-separated")
    ] = None,
    experts_from_mmc: Annotated[
        int | None,
        typer.Option(
            min=1,
            max=8,  # trainingspec.MAX_EXPERTS: a task uses at most 8 experts
            help="buy K expert models from the MMC first (allocateModel: the closest models "
            "by QoS, each paid its price) and train with them and their QoS (K <= 8, the "
            "experts a task can use)",
        ),
    ] = None,
    expert_allocation: Annotated[
        int | None, typer.Option(min=1, help="use the models of your MMC allocation ID")
    ] = None,
    expert_price_wei: Annotated[
        int | None,
        typer.Option(min=0, help="with --experts-from-mmc: wei per model (default: the minimum)"),
    ] = None,
    expert_rate: Annotated[
        float | None, typer.Option(help="R_E: share of expert-guided episodes (0-1)")
    ] = None,
    expert_rate_end: Annotated[
        float | None,
        typer.Option(
            help="R_E at the end of --steps, reached linearly from --expert-rate "
            "(default: R_E fixed, as Alg. 5.1)"
        ),
    ] = None,
    expert_threshold: Annotated[
        float | None, typer.Option(help="l: follow an expert action only above this probability")
    ] = None,
    expert_credit: Annotated[
        bool,
        typer.Option(
            "--expert-credit",  # a flag alone: a --no- twin widened every row of --help
            help="expert credit rule: PPO learns from an expert only once its episodes are "
            "shorter than the agents' own, and unhelpful experts fade out (resilience to "
            "faulty shared models; not in Alg. 5.1)"
        ),
    ] = False,
    keep_best: Annotated[
        str | None,
        typer.Option(
            help="deliver the run's best evaluated policy, by 'time' (shortest episodes) or "
            "'cost' (fewest moves), instead of its last one (spec selection.keep_best)"
        ),
    ] = None,
    public_outcome: Annotated[
        bool,
        typer.Option(
            "--public-outcome",
            help="let the outcome's weights be public (default: sealed to your key, "
            "readable by you only until the worker shares the model)"
        ),
    ] = False,
    as_json: JsonOpt = False,
) -> None:
    """Submit a training task: the spec goes to the content store, the chain recruits."""
    if spec is not None:
        sources = {n: ctx.get_parameter_source(n) for n in SPEC_OPTIONS}
        given = [f"--{n.replace('_', '-')}" for n, src in sources.items()
                 if src is not None and src.name != "DEFAULT"]
        if given:
            raise typer.BadParameter(
                f"{spec} is the whole task body: set what {', '.join(given)} would in the "
                f"file (not read with --spec)", param_hint="--spec")
    sources = [o for o in (experts, experts_from_mmc, expert_allocation) if o is not None]
    if len(sources) > 1:
        raise typer.BadParameter("give one of --experts, --experts-from-mmc, --expert-allocation")
    if not sources and (
        expert_rate is not None
        or expert_threshold is not None
        or expert_credit
        or expert_rate_end is not None
    ):
        raise typer.BadParameter(
            "--expert-rate/--expert-rate-end/--expert-threshold/--expert-credit need experts"
        )
    if expert_price_wei is not None and experts_from_mmc is None:
        raise typer.BadParameter("--expert-price-wei prices --experts-from-mmc")
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
        experts=experts,
        expert_qos=expert_qos,
        expert_rate=expert_rate,
        expert_threshold=expert_threshold,
        expert_credit=expert_credit,
        expert_rate_end=expert_rate_end,
        keep_best=keep_best,
    )
    if experts_from_mmc is not None and not isinstance(body.get("env"), dict):
        raise typer.BadParameter(  # a --spec without one: "error: 'env'" after signing in
            f"{spec}: --experts-from-mmc buys experts for the task's env, and the file has no "
            f"env object", param_hint="--spec")
    with connect_funded(gateway, key, create=True) as gw:
        if not public_outcome and gw.account is not None:
            body.setdefault("outcome_key", public_key_hex(bytes(gw.account.key)))
        try:
            if experts_from_mmc is not None:
                alloc = request_models(
                    gw,
                    body["env"],
                    experts_from_mmc,
                    domain=body.get("domain", 0),
                    price_wei=expert_price_wei,
                )
                expert_allocation = alloc["alloc_id"]
                typer.echo(
                    terminal_text(
                        f"allocation {expert_allocation}: experts "
                        + ", ".join(f"{m['cid']} (qos {m['qos']:.3f})" for m in alloc["models"])
                    ),
                    err=True,
                )
            if expert_allocation is not None:
                body["expert_allocation"] = expert_allocation
            out = submit(gw, body)
            if expert_allocation is not None:
                out["expert_allocation"] = expert_allocation
        except (GatewayError, LookupError) as exc:
            fail_with_register_hint(exc, key)
        emit(out, as_json, lambda d: _submitted(d, key))


def _submitted(d: dict[str, Any], key: Path) -> None:
    typer.echo(
        f"task {d['task_id']} submitted (spec {d['spec_cid']}); offered to: "
        + (", ".join(d.get("offered") or []) or "nobody yet")
    )
    if d.get("allocation_error"):
        typer.echo(
            f"task {d['task_id']} is posted (its payment escrowed) but was not allocated: "
            f"{d['allocation_error']}; allocate it with `drlaas task allocate {d['task_id']} "
            f"--key {key}` rather than submitting it again",
            err=True,
        )
    elif not d.get("offered"):
        typer.echo(allocate_hint(d["task_id"], str(key)), err=True)


def allocate_hint(task_id: int, key: str) -> str:
    """What to run for a task no worker will train: the chain offers a task when it is
    allocated (at submit, and on request), not when a worker registers later."""
    return (
        f"task {task_id} waits for no worker (no live offer, no worker holds it): once "
        f"workers have registered, offer it with `drlaas task allocate {task_id} --key {key}`"
    )


def unallocated(task: dict[str, Any], now: float) -> bool:
    """An open task that no worker holds and no live offer waits on: nobody will train it
    until it is allocated again."""
    if task.get("status") != "open":
        return False
    return not any(
        o.get("state") in HOLDING_STATES
        or (o.get("state") == "offered" and (o.get("expiry") or 0) > now)
        for o in task.get("offers") or []
    )


def submit(gw: Gateway, body: dict[str, Any]) -> dict[str, Any]:
    """Create and allocate a task; ``{task_id, spec_cid, offered, tx_hashes}`` either way: the
    gateway signs both transactions (it holds the key), or we relay ``addTask`` and then
    allocate (the gateway answered ``sign_locally``)."""
    out = write(  # addTask: these terms, escrowing payment_wei x num_workers
        gw, "POST", "/tasks", body, expect=Expect("task submit", (add_task_call(body),))
    )
    if "task_id" in out:
        return out
    task_id = int(event_arg(out, "TaskAdded", "taskId"))
    spec_cid = str(event_arg(out, "TaskAdded", "description"))
    try:
        alloc = write(gw, "POST", f"/tasks/{task_id}/allocate", expect=allocate_expect(task_id))
    except GatewayError as exc:  # the task is posted and holds its escrow: say which it is
        return {"task_id": task_id, "spec_cid": spec_cid, "offered": [],
                "tx_hashes": [out["tx_hash"]], "allocation_error": str(exc)}
    return {
        "task_id": task_id,
        "spec_cid": spec_cid,
        "offered": [e["args"]["worker"] for e in alloc["events"] if e["name"] == "TaskOffered"],
        "tx_hashes": [out["tx_hash"], alloc["tx_hash"]],
    }


def allocate_expect(task_id: int) -> Expect:
    """What ``POST /tasks/{id}/allocate`` may have us sign: TMC.allocateTask(task_id)."""
    return Expect(f"task allocate {task_id}", (Call(TMC, "allocateTask", {"taskId": task_id}),))


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
                [
                    t | {"environment": env_summary(t), "deadline": utc_time(t.get("deadline"))}
                    for t in d["data"]
                    if isinstance(t, dict)
                ],
                [
                    ("id", "ID"),
                    ("status", "STATUS"),
                    ("environment", "ENVIRONMENT"),
                    ("requester", "REQUESTER"),
                    ("num_workers", "WORKERS"),
                    ("offered", "OFFERED"),
                    ("reward_eth", "ETH/WORKER"),
                    ("deadline", "DEADLINE"),
                ],
            )
        ),
    )


def env_summary(task: dict[str, Any]) -> str:
    """``10x10 3 agents 0 walls 4 moves I=1e+09`` from a listed task's ``env`` (its spec CID
    when it has none): units spelt out, as ``4m`` read as four minutes."""
    env = task.get("env")
    if not env:
        return f"spec {task.get('description')}"
    try:
        lo, hi = env["walls"]
        values = ",".join(f"{v:.0e}" for v in env["intensity"]["values"])
        walls = f"{lo}" if lo == hi else f"{lo}-{hi}"
        return (
            f"{env['rows']}x{env['cols']} {env['agents']} agents {walls} walls "
            f"{env['moves']} moves I={values}"
        )
    except (KeyError, IndexError, TypeError, ValueError):  # a gateway's env of another shape
        return "?"


def utc_time(unix: Any) -> Any:
    """A chain timestamp (Unix seconds) as ``2026-12-03 18:40Z``; anything else as it is."""
    if not isinstance(unix, int) or isinstance(unix, bool):
        return unix
    try:
        return dt.datetime.fromtimestamp(unix, dt.UTC).strftime("%Y-%m-%d %H:%MZ")
    except (OverflowError, OSError, ValueError):  # beyond what a datetime holds
        return unix


@task_app.command("show")
def task_show(
    task_id: int,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
    spec_only: Annotated[
        bool,
        typer.Option(
            "--spec",
            help="print only the task's spec document (the CID on chain), e.g. to train it "
            "locally with `drlaas train --task FILE`",
        ),
    ] = False,
) -> None:
    """A task with its offers, outcomes and the live training curve."""
    out = read(gateway, f"/tasks/{task_id}")
    if spec_only:
        if not isinstance(out.get("spec"), dict):
            fail(LookupError(f"task {task_id}: its description {out.get('description')!r} is "
                             "no spec document the gateway could read"))
        typer.echo(json.dumps(out["spec"], indent=1))
        return

    def render(d: dict[str, Any]) -> None:
        typer.echo(
            kv(
                d | {"deadline": utc_time(d.get("deadline"))},
                ["id", "status", "requester", "num_workers", "deadline", "description"],
            )
        )
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
        if d.get("experts"):
            rows = [x | {"suggested": trial_text(x)} for x in d["experts"]]
            typer.echo(
                "\nexperts\n"
                + table(
                    rows,
                    [
                        ("cid", "CID"),
                        ("qos", "QOS"),
                        ("model_id", "MODEL"),
                        ("reputation", "REPUTATION"),
                        ("alloc_id", "ALLOCATION"),
                        ("suggested", "SUGGESTED (TRIAL)"),
                        ("review", "REVIEW"),
                    ],
                )
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


def trial_text(expert: dict[str, Any]) -> str:
    """The workers' trials of an expert (``experts[].trials``, one per outcome card): one as
    "K/5 (time steps, ratio x oracle)"; several as the gateway's ``suggested_review`` (their
    middle one, ``review.middle_review``) and each one's; "" when none has one."""
    trials = expert.get("trials") or []
    if not trials:
        return ""
    if len(trials) > 1:
        each = sorted(int(t["suggested_review"]) for t in trials)
        return (f"{expert.get('suggested_review')}/5 (middle of {len(each)}: "
                + ", ".join(map(str, each)) + ")")
    t, ratio = trials[0], trials[0].get("time_vs_oracle")
    return (f"{t['suggested_review']}/5 ({t['time']:.1f} steps"
            + (f", {ratio:.2f}x oracle)" if ratio is not None else ")"))


@task_app.command("review")
def task_review(
    task_id: int,
    worker: Annotated[str, typer.Option(help="worker whose outcome you review")],
    review: Annotated[int, typer.Option(min=0, max=5, help="0-5")],
    key: OwnKeyOpt,
    reject: Annotated[bool, typer.Option(help="reject the outcome (no payment)")] = False,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Review a worker's outcome (TMC.reviewOutcome): pays and updates its reputation."""
    with connect_funded(gateway, key) as gw:
        try:
            out = write(
                gw,
                "POST",
                f"/tasks/{task_id}/reviews",
                {"worker": worker, "review": review, "accepted": not reject},
                expect=Expect(
                    "task review",
                    (
                        Call(
                            TMC,
                            "reviewOutcome",
                            {
                                "taskId": task_id,
                                "worker": worker,
                                "review": review,
                                "accepted": not reject,
                            },
                        ),
                    ),
                ),
            )
        except GatewayError as exc:
            fail(exc)
    emit(out, as_json, lambda d: typer.echo(f"reviewed {worker} on task {task_id}: {review}/5"))


@task_app.command("allocate")
def task_allocate(
    task_id: int,
    key: OwnKeyOpt,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Offer the task's open slots to the best workers again (TMC.allocateTask): after a
    submit whose allocation failed, or once offers expired or were declined."""
    with connect_funded(gateway, key) as gw:
        try:
            out = write(gw, "POST", f"/tasks/{task_id}/allocate", expect=allocate_expect(task_id))
        except GatewayError as exc:
            fail(exc)
    emit(out, as_json, lambda d: typer.echo(f"task {task_id} allocated ({d['tx_hash']})"))


CANCEL_REFUSED = {
    "tasks_not_open": "task {id} is no longer open: only an open task can be cancelled",
    "tasks_has_accepted_workers": "a worker has accepted task {id}: it can no longer be "
    "cancelled (wait for its outcome, or for the deadline to close it)",
    "tasks_has_live_offers": "task {id} is offered to a worker who may still accept it: "
    "cancel it once the offer expires (`drlaas task show {id}` lists the offers)",
    "tasks_deadline_passed": "task {id} is past its deadline: it can no longer be cancelled, "
    "closing it refunds what no worker earned",
}
"""The chain's refusals of a cancel (TMC.updateTaskStatus, as the gateway names them), said as
what is wrong with the task and what to do."""


def cancel_expect(task_id: int) -> Expect:
    """What ``POST /tasks/{id}/cancel`` may have us sign: TMC.updateTaskStatus(id, Cancelled)."""
    return Expect(
        f"task cancel {task_id}",
        (Call(TMC, "updateTaskStatus", {"taskId": task_id, "status": int(TaskStatus.CANCELLED)}),),
    )


@task_app.command("cancel")
def task_cancel(
    task_id: int,
    key: OwnKeyOpt,
    yes: Annotated[bool, typer.Option("--yes", "-y", help="do not ask for confirmation")] = False,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Cancel your open task before any worker accepted it (TMC.updateTaskStatus): its escrow
    is refunded to your credit on the TasksManager."""
    with connect_funded(gateway, key) as gw:
        task = _own_open_task(gw, task_id, key)
        if not yes:
            typer.confirm(
                f"Cancel task {task_id} ({env_summary(task)}; {task.get('num_workers')} "
                f"worker(s) x {task.get('reward_eth')} ETH escrowed)?",
                abort=True,
            )
        try:
            out = write(gw, "POST", f"/tasks/{task_id}/cancel", expect=cancel_expect(task_id))
        except GatewayError as exc:
            rule = exc.detail.get("rule") if isinstance(exc.detail, dict) else None
            fail(RuntimeError(CANCEL_REFUSED[rule].format(id=task_id))
                 if rule in CANCEL_REFUSED else exc)
        refunded = sum(
            int(e["args"]["amount"])
            for e in out.get("events") or []
            if e.get("name") == "PaymentCredited"
            and str(e["args"].get("account", "")).lower() == gw.address.lower()
        )
    emit(
        {**out, "task_id": task_id, "refunded_wei": refunded},
        as_json,
        lambda d: typer.echo(
            f"task {task_id} cancelled ({d['tx_hash']})"
            + (f"; {wei_to_eth(refunded)} ETH refunded to your credit on the TasksManager"
               if refunded else "")
        ),
    )


def _own_open_task(gw: Gateway, task_id: int, key: Path) -> dict[str, Any]:
    """Task ``task_id`` if it is open and the key's; else exit 1 saying which it is not."""
    try:
        task = gw.get(f"/tasks/{task_id}")
    except GatewayError as exc:
        if exc.status == 404:
            fail(LookupError(f"no task {task_id} on {gw.url} (`drlaas task list` lists them)"))
        fail(exc)
    if str(task.get("requester", "")).lower() != gw.address.lower():
        fail(PermissionError(
            f"task {task_id} is not yours: its requester is {task.get('requester')}, "
            f"{key} is {gw.address}; give the key that submitted it"))
    if task.get("status") != "open":
        fail(RuntimeError(
            f"task {task_id} is {task.get('status')}: only an open task can be cancelled"))
    return dict(task)


@task_app.command("wait")
def task_wait(
    task_id: int,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    timeout: Annotated[float, typer.Option(min=1, help="seconds before giving up")] = 1800,
    as_json: JsonOpt = False,
) -> None:
    """Wait until a worker submits an outcome for the task (or the task ends); training
    progress is printed as it arrives. Exit 1 on timeout or when the task ended without one,
    or when the gateway still knows no such task after 30 s."""
    started = time.monotonic()
    deadline = started + timeout
    shown = 0
    said_missing = said_unallocated = False
    with connect(gateway) as gw:
        while True:
            try:
                d = terminal_safe(gw.get(f"/tasks/{task_id}"))
            except GatewayError as exc:
                now = time.monotonic()
                if exc.status != 404 or now > min(deadline, started + NOT_INDEXED_GRACE_S):
                    fail(exc)
                if not said_missing:  # 404 right after a submit: the indexer may lag
                    typer.echo(
                        f"task {task_id}: not known to the gateway yet; waiting up to "
                        f"{NOT_INDEXED_GRACE_S:g} s for it to appear",
                        err=True,
                    )
                    said_missing = True
                time.sleep(2.0)
                continue
            if not said_unallocated and unallocated(d, time.time()):
                typer.echo(allocate_hint(task_id, "<your key>"), err=True)
                said_unallocated = True
            for p in (d.get("progress") or [])[shown:]:
                typer.echo(
                    f"task {task_id}: step {p.get('step')} success {p.get('success')}", err=True
                )
            shown = max(shown, len(d.get("progress") or []))
            if d.get("outcomes"):
                break
            if d.get("status") in ("cancelled", "closed", "completed"):
                fail(RuntimeError(f"task {task_id} is {d['status']} with no outcome"))
            if time.monotonic() > deadline:
                fail(
                    TimeoutError(
                        f"task {task_id}: no outcome after {timeout:g} s ({d.get('status')})"
                    )
                )
            time.sleep(2.0)
    emit(
        d["outcomes"],
        as_json,
        lambda o: typer.echo(
            "\n".join(f"task {task_id}: outcome {x['cid']} from {x['worker']}" for x in o)
        ),
    )


@task_app.command("pull")
def task_pull(
    task_id: int,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="new or empty folder (default ./task-<ID>-model)"),
    ] = None,
    force: ForceOpt = False,
    worker: Annotated[str | None, typer.Option(help="whose outcome (default: the first)")] = None,
    key: Annotated[
        Path | None,
        typer.Option("--key", envvar="DRLAAS_KEY", help="your key: opens an outcome sealed to you"),
    ] = None,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Download a task's outcome model through the gateway, verified against its CID (the
    requester does not have to wait until the worker shares it; a sealed outcome is opened
    here with the requester's --key). The CID the gateway names is checked on chain first
    (TMC.outcomeOf: an outcome of this task by that worker, at the pinned TasksManager); with
    --key the bundle must be sealed."""
    try:  # before anything is read or pinned for it: a mistyped --key is named, not used
        private_key = bytes(load_key(key).key) if key is not None else None
    except (OSError, ValueError) as exc:
        fail(exc)
    doc = read(gateway, f"/tasks/{task_id}")
    outcomes = doc.get("outcomes") if isinstance(doc, dict) else None
    if not isinstance(outcomes, list) or not all(
        isinstance(o, dict) and isinstance(o.get("worker"), str) and isinstance(o.get("cid"), str)
        for o in outcomes
    ):
        fail(GatewayError("GET", f"/tasks/{task_id}", 200, "'outcomes' is not a list of "
                          "{worker, cid} objects"))
    chosen = [o for o in outcomes if worker is None or o["worker"].lower() == worker.lower()]
    if not chosen:
        fail(LookupError(f"task {task_id} has no outcome" + (f" from {worker}" if worker else "")))
    cid = chosen[0]["cid"]
    path = out if out is not None else Path(f"task-{task_id}-model")
    try:
        check_outcome_on_chain(gateway, key, task_id, chosen[0]["worker"], cid)
    except (ValueError, LookupError, GatewayError) as exc:
        fail(exc)
    except Exception as exc:  # noqa: BLE001 - web3 raises several types; shown with its type
        fail(RuntimeError(f"cannot read task {task_id}'s outcome on chain: "
                          f"{type(exc).__name__}: {exc}"))
    try:
        with GatewayBlocks(gateway) as store:
            if private_key is not None and SEALED_FILE not in sealed_envelopes(store, cid):
                fail(ValueError(
                    f"outcome {cid} of task {task_id} is not sealed, and --key (or DRLAAS_KEY) "
                    "asks for an outcome sealed to you: pull it without --key if the task was "
                    "submitted with --public-outcome"))
            pulled = pull_into(store, cid, path, force,
                               lambda d: pull_model_with_key(store, cid, d, private_key))
    except typer.Exit:
        raise
    except Exception as exc:  # noqa: BLE001 - shown to the user with its type
        fail(RuntimeError(f"cannot pull {cid}: {type(exc).__name__}: {exc}"))
    emit(
        {"task_id": task_id, "worker": chosen[0]["worker"], "cid": cid, "path": str(path),
         "pulled": pulled},
        as_json,
        lambda d: typer.echo(f"task {task_id} outcome {cid} ({d['worker']}) -> {path}" if pulled
                             else f"task {task_id} outcome {cid}: {path} already holds it"),
    )


def check_outcome_on_chain(
    gateway: str, key: Path | None, task_id: int, worker: str, cid: str
) -> None:
    """ValueError unless the chain (DRLAAS_CHAIN, or the gateway's /rpc; the pinned chain id
    and TasksManager) records ``cid`` as ``worker``'s outcome of ``task_id``."""
    with CliGateway(gateway or DEFAULT_GATEWAY, None, key) as gw:
        tmc = pinned_contract(gw, key, TMC)
        owner, on_task, _ = tmc.functions.outcomeOf(cid_hash(cid)).call()
    if int(owner, 16) == 0:
        raise ValueError(
            f"the gateway names {cid} as task {task_id}'s outcome, but the chain records no "
            f"outcome with that CID (TasksManager {tmc.address})"
        )
    if str(owner).lower() != worker.lower() or int(on_task) != task_id:
        raise ValueError(
            f"the gateway names {cid} as {worker}'s outcome of task {task_id}, but the chain "
            f"records it as {owner}'s outcome of task {on_task}"
        )
