"""``drlaas model ...``: shared models: list, show, pull (through the gateway, CID-verified),
share; model-sharing requests to the MMC (``request``: allocateModel, Eq. 10-13 / 22-23, paid
per model), an allocation's models (``allocation``) and their reviews (``review``:
updateModelRep, Eq. 10-11)."""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from backend.store import NotFound, StoreError
from backend.store.bundle import MAX_CARD_BYTES, model_files, pull_model
from backend.store.dag import compute_cid
from backend.store.gateway_blocks import GatewayBlocks
from drlaas.commands.client.session import (
    DEFAULT_GATEWAY,
    CliGateway,
    GatewayOpt,
    JsonOpt,
    KeyOpt,
    OwnKeyOpt,
    connect_funded,
    emit,
    event_arg,
    fail,
    kv,
    read,
    table,
    write,
)
from drlaas.commands.client.txcheck import (
    MMC,
    TMC,
    Call,
    Expect,
    allocate_model_call,
    pinned_contract,
    share_model_expect,
)
from drlaas.commands.client.users import fail_with_register_hint
from workers.daemon.gateway import Gateway, GatewayError
from workers.daemon.keys import load_key
from workers.mdrl.spec import parse_grid, parse_walls
from workers.mdrl.trainingspec import SpecError, parse_env

model_app = typer.Typer(
    help="Shared models: list, show, pull, push (to the store), share, request (from the "
    "MMC), allocation, review.",
    no_args_is_help=True,
)


ForceOpt = Annotated[
    bool, typer.Option("--force", help="replace a non-empty --out folder (its files are deleted)")
]


def pull_into(
    store: Any, cid: str, dest: Path, force: bool, fetch: Callable[[Path], Any]
) -> bool:
    """``fetch`` model bundle ``cid`` into ``dest``; False when ``dest`` already holds exactly
    its files (nothing done). Files of the user's are never overwritten: a folder that holds
    anything else is refused (exit 1) unless ``force``, which replaces it. The model is
    fetched into a new folder beside ``dest`` first, so a pull that fails changes nothing."""
    if dest.exists() and not dest.is_dir():
        fail(NotADirectoryError(f"--out {dest} is a file, not a folder: give another --out"))
    occupied = dest.is_dir() and any(dest.iterdir())
    if occupied and not force:
        if holds_bundle(store, cid, dest):
            return False
        fail(FileExistsError(
            f"--out {dest} is not empty: the model would overwrite its files; give a new or "
            f"empty folder, or --force to replace {dest} and everything in it"))
    target = dest.resolve()
    if occupied and Path.cwd().resolve().is_relative_to(target):
        fail(ValueError(f"--out {dest} holds the current directory: it is not replaced; "
                        "give another --out"))
    target.parent.mkdir(parents=True, exist_ok=True)
    fresh = target.parent / f".{target.name}.pulling-{os.getpid()}"
    shutil.rmtree(fresh, ignore_errors=True)  # left by a pull that was killed
    fresh.mkdir()
    try:
        fetch(fresh)
        if occupied:
            shutil.rmtree(target)
        if target.is_dir():  # an empty folder stays (it may be the current directory)
            for f in fresh.iterdir():
                f.replace(target / f.name)
        else:
            fresh.rename(target)
    finally:
        shutil.rmtree(fresh, ignore_errors=True)
    return True


def holds_bundle(store: Any, cid: str, folder: Path) -> bool:
    """Whether ``folder`` holds exactly the files of model bundle ``cid``, each with its CID
    (a file is read only when it has the size the manifest declares)."""
    files = model_files(store, cid)
    if sorted(p.name for p in folder.iterdir()) != sorted(files):
        return False
    return all(
        (folder / name).is_file()
        and (folder / name).stat().st_size == size
        and compute_cid((folder / name).read_bytes()) == file_cid
        for name, (file_cid, size) in files.items()
    )


def fetch_model(cid: str, kind: str) -> Path:
    """How `drlaas train` uses a model named by CID (``--experts CID``, or a ``--task`` spec's
    experts and walls CAE): fetched block by block through the gateway ($DRLAAS_GATEWAY) into
    the cache ($DRLAAS_CACHE, default ~/.cache/drlaas; once per CID) and verified as a worker
    verifies it (workers/daemon/experts.py: bounded sizes, no pickle, a card that fits the
    task bounds). ValueError names the CID and what is wrong."""
    from backend.store import StoreUnavailable
    from workers.daemon.experts import ExpertFetchError, fetch_expert, fetch_walls_cae

    gateway = os.environ.get("DRLAAS_GATEWAY", DEFAULT_GATEWAY)
    cache = Path(os.environ.get("DRLAAS_CACHE", Path.home() / ".cache" / "drlaas"))
    fetch = fetch_walls_cae if kind == "walls CAE" else fetch_expert
    try:
        with GatewayBlocks(gateway) as store:
            return fetch(store, cid, cache)
    except StoreUnavailable as exc:
        raise ValueError(
            f"{kind} {cid}: cannot fetch it from the gateway {gateway} (DRLAAS_GATEWAY): {exc}"
        ) from None
    except ExpertFetchError as exc:
        raise ValueError(f"{kind} {exc.cid}: {exc.reason}") from None


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
    """The model page's figures as text (GET /models/{id}: provenance, held-out, curve); a
    field the gateway's answer lacks or holds with another type is shown as ``?``."""
    lines = []
    if d.get("name") or d.get("kind"):
        lines.append(" ".join(str(x) for x in (d.get("name"), d.get("kind")) if x))
    p = d.get("produced_by")
    if p:
        p = _obj(p)
        lines.append(f"produced by task {p.get('task_id', '?')} (worker {p.get('worker', '?')}; "
                     "the chain's outcome record)")
    else:
        lines.append("an owner's upload (no task's outcome)")
    for x in _objs(d.get("experts")):
        where = f"model {x['model_id']}" if x.get("model_id") else "not listed here"
        source = str(x.get("source", "?")).replace("_", " ")
        lines.append(f"expert {x.get('ref', '?')} ({where}; from the {source})")
    held = _obj(d.get("heldout"))
    for f in _objs(held.get("readings")):
        lines.append(
            f"held-out ({held.get('episodes', '?')} episodes, {f.get('reading_model', '?')} "
            f"readings): success {_pct(f.get('success'))}, time {_num(f.get('time'))} (oracle "
            f"{_num(f.get('oracle_time'))}), cost {_num(f.get('cost'))}"
        )
    final = _obj(d.get("final_eval"))
    if final.get("success") is not None:  # what the web page shows, not held out
        lines.append(
            f"final evaluation (the run's own episodes, not held out): success "
            f"{_pct(final['success'])}, time {_num(final.get('time'))} steps, cost "
            f"{_num(final.get('cost'))}"
        )
    curve = _objs(d.get("curve"))
    if curve:
        last = curve[-1]  # training episodes that ended in the last update: not an evaluation
        lines.append(
            f"curve: {len(curve)} points to {last.get('step', '?')} env steps; its last point "
            f"(training episodes that ended then) success {_num(last.get('success'))}, time "
            f"{_num(last.get('time'))}, cost {_num(last.get('cost'))}"
        )
    return lines


def _obj(value: Any) -> dict[str, Any]:
    return value if isinstance(value, dict) else {}


def _objs(value: Any) -> list[dict[str, Any]]:
    return [x for x in value if isinstance(x, dict)] if isinstance(value, list) else []


def _pct(value: Any) -> str:
    return f"{100 * value:.1f}%" if isinstance(value, int | float) else "?"


def _num(value: Any) -> str:
    return f"{value:.2f}" if isinstance(value, int | float) else "-"


@model_app.command("pull")
def model_pull(
    model: Annotated[str, typer.Argument(help="model id or manifest CID")],
    out: Annotated[
        Path | None,
        typer.Option("--out", help="new or empty folder to write the model into (default "
                     "./model-<MODEL>)"),
    ] = None,
    force: ForceOpt = False,
    key: Annotated[
        Path | None,
        typer.Option("--key", envvar="DRLAAS_KEY", help="your key file: a model id's CID is "
                     "checked on the deployment pinned for it"),
    ] = None,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Download a model (model.safetensors + model.json) through the gateway, every block
    verified against its CID; a model id is resolved to its CID by the gateway, which is
    checked on chain first (MMC.getModel, at the pinned ModelsManager). A folder that
    already holds files is left alone unless --force (or it holds this very model)."""
    cid = model
    if model.isdigit():
        cid = model_cid(gateway, key, int(model))
    dest = out if out is not None else default_out(model)
    try:
        with GatewayBlocks(gateway) as store:
            pulled = pull_into(store, cid, dest, force, lambda d: pull_model(store, cid, d))
    except typer.Exit:
        raise
    except Exception as exc:  # noqa: BLE001 - shown to the user with its type
        fail(RuntimeError(f"cannot pull {cid}: {type(exc).__name__}: {exc}"))
    emit({"cid": cid, "path": str(dest), "pulled": pulled}, as_json,
         lambda d: typer.echo(f"model {cid} -> {dest}" if pulled
                              else f"model {cid}: {dest} already holds it"))


def model_cid(gateway: str, key: Path | None, model_id: int) -> str:
    """Model ``model_id``'s CID as the gateway names it, once the chain lists it (exit 1
    naming both otherwise): a gateway cannot hand out another bundle under a listed id."""
    if key is not None:
        try:  # before its pin file is read or written: a mistyped --key is named, not used
            load_key(key)
        except (OSError, ValueError) as exc:
            fail(exc)
    doc = read(gateway, f"/models/{model_id}")
    cid = doc.get("cid") if isinstance(doc, dict) else None
    if not isinstance(cid, str):
        fail(GatewayError("GET", f"/models/{model_id}", 200, "'cid' is not a string"))
    try:
        check_model_on_chain(gateway, key, model_id, cid)
    except (ValueError, LookupError, GatewayError) as exc:
        fail(exc)
    except Exception as exc:  # noqa: BLE001 - web3 raises several types; shown with its type
        fail(RuntimeError(f"cannot read model {model_id} on chain: {type(exc).__name__}: {exc}"))
    return cid


def check_model_on_chain(gateway: str, key: Path | None, model_id: int, cid: str) -> None:
    """ValueError unless the chain (as for `task pull`: DRLAAS_CHAIN or the gateway's /rpc, the
    pinned chain id and ModelsManager) lists ``cid`` as model ``model_id`` (MMC.getModel)."""
    with CliGateway(gateway or DEFAULT_GATEWAY, None, key) as gw:
        mmc = pinned_contract(gw, key, MMC)
        _, listed, _ = mmc.functions.getModel(model_id).call()
    if listed != cid:
        chain = f"lists {listed} as its CID" if listed else "lists no model with that id"
        raise ValueError(
            f"the gateway names {cid} as model {model_id}'s CID, but the chain {chain} "
            f"(ModelsManager {mmc.address}); nothing was pulled"
        )


@model_app.command("push")
def model_push(
    directory: Annotated[Path, typer.Argument(help="a model or walls CAE directory")],
    key: Annotated[
        Path | None,
        typer.Option(
            "--key",
            envvar="DRLAAS_KEY",
            help="your worker key: commit the CID on chain before the upload, so that "
            "`model share` can list it and nobody who reads the store can list it first",
        ),
    ] = None,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Add a model or a walls CAE (model.safetensors + model.json) to the platform's content
    store and print its bundle CID: what a task spec names in experts or
    observation.walls_embedding. Checked here first (safetensors + a card that rebuilds);
    the store is the platform's (DRLAAS_IPFS, or the embedded one of a gateway on this
    machine), as for the worker daemon. With --key the CID is computed first and committed
    (POST /models/commitments, commit-reveal) before anything is uploaded."""
    from backend.chain.platform import cid_commitment
    from backend.store.bundle import upload_model
    from backend.store.staged import StagedUpload
    from workers.daemon.links import open_store, worker_settings

    kind = _check_local_model(directory)
    staged = StagedUpload()
    cid = upload_model(staged, directory)
    out: dict[str, Any] = {"cid": cid, "kind": kind, "path": str(directory)}
    if key is not None:
        with connect_funded(gateway, key, create=True) as gw:
            commitment = "0x" + cid_commitment(cid, gw.account.address).hex()
            try:
                write(
                    gw,
                    "POST",
                    "/models/commitments",
                    {"commitment": commitment},
                    expect=Expect(
                        "model push --key",
                        (Call(TMC, "commitCid", {"commitment": commitment}),),
                    ),
                )
            except GatewayError as exc:
                fail(exc)
        out["commitment"] = commitment
    elif kind == "model":
        typer.echo(
            f"note: {cid} is readable in the store before any commitment to it; to list it "
            "with `model share` and be sure nobody who reads the store lists it first, push "
            "it with --key (commit-reveal, docs/chain.md)",
            err=True,
        )
    try:
        settings, _ = worker_settings(gateway)
        staged.publish(open_store(settings))
    except Exception as exc:  # noqa: BLE001 - shown to the user with its type
        fail(RuntimeError(f"cannot push {directory}: {type(exc).__name__}: {exc}"))
    emit(out, as_json, lambda d: typer.echo(f"{kind} {directory} -> {cid}"))


def _check_local_model(directory: Path) -> str:
    """``"walls CAE"`` or ``"model"`` if ``directory`` loads as one (never unpickles)."""
    from workers.mdrl.modelio import model_file

    try:  # a regular file within the bound of a card: a nested one raised RecursionError
        with model_file(directory, "model.json").open("rb") as fh:
            raw = fh.read(MAX_CARD_BYTES + 1)
        if len(raw) > MAX_CARD_BYTES:
            raise ValueError(f"more than {MAX_CARD_BYTES} bytes, the bound of a model card")
        card = json.loads(raw)
    except (OSError, ValueError, RecursionError) as exc:
        fail(ValueError(f"{directory}: no readable model.json ({exc})"))
    try:
        if isinstance(card, dict) and card.get("kind") == "cae":
            from workers.mdrl.cae import load_cae

            load_cae(directory)
            return "walls CAE"
        from workers.mdrl.modelio import load_model

        load_model(directory)
        return "model"
    except Exception as exc:  # noqa: BLE001 - what is wrong with the files, for the user
        fail(ValueError(f"{directory} is not a model or walls CAE directory: {exc}"))
    raise AssertionError("unreachable")


@model_app.command("share")
def model_share(
    cid: Annotated[str, typer.Option(help="manifest CID of the model")],
    key: KeyOpt,
    env_json: Annotated[
        str | None,
        typer.Option("--env", help="EnvSpec JSON the model was trained on (default: its card's)"),
    ] = None,
    description: str = "",
    domain: int = 0,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Share a model (MMC.addModel) so requesters can be allocated it; its environment is the
    one its card (model.json, read from the store) names."""
    declared = env_option(env_json) if env_json is not None else None
    body = {"cid": cid, "description": description, "domain": domain,
            "env": shared_env(gateway, cid, declared)}
    with connect_funded(gateway, key, create=True) as gw:
        try:
            out = write(
                gw, "POST", "/models", body, expect=share_model_expect("model share", body, gw)
            )
        except GatewayError as exc:
            fail(exc)
    emit(out, as_json, lambda d: typer.echo(shared_line(d, cid)))


def env_option(text: str) -> Any:
    """The ``--env`` option's JSON object; a usage error naming it when it is not one."""
    try:
        env = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise typer.BadParameter(f"not JSON ({exc})", param_hint="--env") from None
    if not isinstance(env, dict):
        raise typer.BadParameter("a JSON object, e.g. '{\"rows\": 10, \"cols\": 10, "
                                 "\"agents\": 3}'", param_hint="--env")
    return env


def shared_env(gateway: str, cid: str, declared: dict[str, Any] | None) -> dict[str, Any]:
    """The environment to share bundle ``cid`` with: its card's (the gateway refuses any other),
    read from the store; a ``declared`` one (--env) that differs is a usage error naming the
    fields of both."""
    try:
        with GatewayBlocks(gateway) as store:
            card_cid, size = model_files(store, cid)["model.json"]
            card = json.loads(store.get(card_cid, max_size=size))
    except NotFound:
        fail(LookupError(f"the content store has no {cid}: push the model first "
                         "(`drlaas model push DIR --key K`)"))
    except (StoreError, ValueError, RecursionError) as exc:
        fail(ValueError(f"cannot read the card (model.json) of {cid}: {exc}"))
    env = card.get("env") if isinstance(card, dict) else None
    if not isinstance(env, dict):
        fail(ValueError(f"the card (model.json) of {cid} names no environment ('env'): it is "
                        "no model to share"))
    if declared is None:
        return env
    try:
        mine, theirs = parse_env(declared, field="").to_dict(), parse_env(env, field="").to_dict()
    except SpecError as exc:
        raise typer.BadParameter(f"{exc.field}: {exc.msg}".lstrip(": "),
                                 param_hint="--env") from None
    differ = [k for k in mine if mine[k] != theirs.get(k)]
    if differ:
        raise typer.BadParameter(
            "disagrees with the card of the model: --env has "
            + ", ".join(f"{k}={mine[k]!r}" for k in differ) + ", the card "
            + ", ".join(f"{k}={theirs.get(k)!r}" for k in differ)
            + "; leave --env out to share it with the card's environment",
            param_hint="--env",
        )
    return env


def shared_line(answer: dict[str, Any], cid: str) -> str:
    """``model ID shared: CID``. The id is the gateway's answer (``id``) when it signed the
    write, else the ``ModelAdded`` event of the receipt we relayed, which has no ``id`` field
    (left out only when that receipt came from the chain's JSON-RPC, without events)."""
    try:
        model_id = answer["id"] if "id" in answer else event_arg(answer, "ModelAdded", "modelId")
    except LookupError:
        return f"model shared: {cid} (its id: `drlaas model list --q {cid}`)"
    return f"model {model_id} shared: {cid}"


def request_models(
    gw: Gateway,
    env: dict[str, Any],
    num_models: int,
    *,
    domain: int = 0,
    price_wei: int | None = None,
    metric: str = "sharing",
) -> dict[str, Any]:
    """MMC.allocateModel for ``num_models`` models fitting ``env``: ``{alloc_id, models: [{id,
    cid, qos, ...}]}``, whether the gateway signed it or we relayed it (then the models are
    read back from ``GET /models/requests/{id}``)."""
    body: dict[str, Any] = {"domain": domain, "env": env, "num_models": num_models}
    body["metric"] = metric
    if price_wei is not None:
        body["price_wei"] = price_wei
    out = write(  # paid price_wei (or the MMC's minimum) x num_models
        gw,
        "POST",
        "/models/requests",
        body,
        expect=Expect("model request", (allocate_model_call(body),)),
    )
    if "alloc_id" in out:
        return dict(out)
    alloc_id = int(event_arg(out, "ModelsRequested", "allocId"))
    return dict(gw.get(f"/models/requests/{alloc_id}"))


def _show_allocation(d: dict[str, Any]) -> None:
    typer.echo(f"allocation {d['alloc_id']}")
    typer.echo(
        table(
            d["models"],
            [
                ("id", "MODEL"),
                ("qos", "QOS"),
                ("review", "REVIEW"),
                ("owner", "OWNER"),
                ("cid", "CID"),
            ],
        )
    )


@model_app.command("request")
def model_request(
    key: KeyOpt,
    num_models: Annotated[int, typer.Option(min=1, max=16, help="models to allocate (K)")] = 1,
    grid: Annotated[str, typer.Option(help="ROWSxCOLS of the task the models should fit")] = (
        "10x10"
    ),
    agents: Annotated[int, typer.Option(min=1)] = 3,
    walls: Annotated[str, typer.Option(help="count or range, e.g. 0-2")] = "0",
    env_json: Annotated[
        str | None, typer.Option("--env", help="EnvSpec JSON instead of --grid/--agents/--walls")
    ] = None,
    domain: int = 0,
    metric: Annotated[str, typer.Option(help="sharing (Eq. 22-23) | model (Eq. 13)")] = "sharing",
    price_wei: Annotated[
        int | None, typer.Option(min=0, help="wei per model (default: the MMC's minimum)")
    ] = None,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Ask the MMC for K models fitting a task (allocateModel; each is paid to its owner). Use
    the allocation's models as experts with `drlaas task submit --expert-allocation ID`."""
    if metric not in ("sharing", "model"):
        raise typer.BadParameter("sharing or model", param_hint="--metric")
    if env_json is not None:
        env = env_option(env_json)
    else:
        try:
            rows, cols = parse_grid(grid)
            env = {"rows": rows, "cols": cols, "agents": agents,
                   "walls": list(parse_walls(walls))}
        except ValueError as exc:
            raise typer.BadParameter(str(exc)) from None
    with connect_funded(gateway, key, create=True) as gw:
        try:
            out = request_models(
                gw, env, num_models, domain=domain, price_wei=price_wei, metric=metric
            )
        except (GatewayError, LookupError) as exc:
            fail_with_register_hint(exc, key)
    emit(out, as_json, _show_allocation)


@model_app.command("allocation")
def model_allocation(
    alloc_id: int, gateway: GatewayOpt = DEFAULT_GATEWAY, as_json: JsonOpt = False
) -> None:
    """An MMC allocation: its models, their QoS and your reviews."""
    emit(read(gateway, f"/models/requests/{alloc_id}"), as_json, _show_allocation)


@model_app.command("review")
def model_review(
    alloc_id: Annotated[int, typer.Argument(help="the allocation that gave you the model")],
    model_id: Annotated[int, typer.Option("--model", min=1, help="the model reviewed")],
    review: Annotated[int, typer.Option(min=0, max=5, help="0-5")],
    key: OwnKeyOpt,
    gateway: GatewayOpt = DEFAULT_GATEWAY,
    as_json: JsonOpt = False,
) -> None:
    """Review a model you were allocated (MMC.updateModelRep, once per allocation): moves the
    model's reputation (Eq. 11) and its owner's (Eq. 10)."""
    with connect_funded(gateway, key) as gw:
        try:
            out = write(
                gw,
                "POST",
                f"/models/requests/{alloc_id}/reviews",
                {"model_id": model_id, "review": review},
                expect=Expect(
                    "model review",
                    (
                        Call(
                            MMC,
                            "updateModelRep",
                            {"allocId": alloc_id, "modelId": model_id, "review": review},
                        ),
                    ),
                ),
            )
        except GatewayError as exc:
            fail(exc)
    emit(
        out,
        as_json,
        lambda d: typer.echo(f"reviewed model {model_id} of allocation {alloc_id}: {review}/5"),
    )
