"""``drlaas demo-scenario``: the scripted scenario of issue 4 (item 8) against a running
platform (``drlaas up``), through REST only.

A requester and three workers register; a training task is submitted; the chain recruits; a
worker trains with a short budget while its progress shows; the model's manifest goes to the
content store and its CID on chain; the requester reviews it; reputations change; the model
owner shares it and it shows in the listing; a second requester asks for experts (a
model-sharing task), receives that model's CID and trains a second task with it as the
expert (MEDC, thesis Alg. 5.1: the outcome's card lists the expert and the episodes it
guided, and the worker's trial of it on the task), then accepts that outcome and reviews the
expert as the trial suggests, which sets its reputation on chain (Eq. 11). Finally the workers
publish the model zoo (``models/``: one trained model per thesis row, uploaded with its card),
so the listing shows what the platform sells.

The requesters are demo users whose keys the development gateway holds (``user1``, ``user2``:
the chain's funded accounts 1 and 2, random per data directory on the embedded chain); the
workers sign with their own key files from ``<data>/keys`` (the gateway holds none of them,
so their writes go through ``sign_locally``).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer
from eth_account import Account

from backend.settings import load_settings
from drlaas.commands.client import write
from drlaas.commands.up import running_platform
from workers.daemon.gateway import Gateway, GatewayError

SCENARIO_ENV = {"rows": 6, "cols": 6, "agents": 2, "walls": [0, 0]}
#: The shipped models (workers/mdrl/zoo.py) the demo workers publish.
ZOO_DIR = Path(__file__).resolve().parents[2] / "models"
DEMO_REQUESTERS = ("user1", "user2")  # demo users of the gateway: chain accounts 1 and 2


class DemoUser(Gateway):
    """A demo user of a development gateway, on this machine: the gateway holds its key (the
    embedded chain's accounts are random per data directory, a dev node's come from its
    mnemonic) and signs its transactions; its token comes from ``POST /auth/demo-token``."""

    def __init__(self, url: str, name: str) -> None:
        super().__init__(url)
        users = {u["name"]: u["address"] for u in self.get("/auth/demo-users")["data"]}
        if name not in users:
            raise LookupError(f"no demo user {name!r} at {url}; it has {sorted(users)}")
        self.name, self._address = name, str(users[name])

    @property
    def address(self) -> str:
        return self._address

    def sign_in(self) -> str:
        body = {"name": self.name, "address": self._address}
        self._token = str(self.post("/auth/demo-token", body)["access_token"])
        return self._token


def wait_for(
    what: str,
    fetch: Callable[[], Any],
    ok: Callable[[Any], bool],
    timeout: float,
    every: float = 0.25,
) -> Any:
    """Poll ``fetch`` until ``ok(value)``; TimeoutError naming ``what`` and the last value."""
    deadline = time.monotonic() + timeout
    while True:
        value = fetch()
        if ok(value):
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(
                f"timed out after {timeout:.0f} s waiting for {what}; last: "
                f"{json.dumps(value, default=str)[:1500]}"
            )
        time.sleep(every)


def _register_requester(gw: Gateway) -> None:
    try:
        write(gw, "POST", "/users/requesters")
    except GatewayError as exc:
        if not (exc.status == 409 and "already" in str(exc.detail)):
            raise


def run_scenario(
    url: str,
    data_dir: Path,
    *,
    steps: int = 2000,
    timeout: float = 300.0,
    say: Callable[[str], None] = print,
    requesters: tuple[str, str] = DEMO_REQUESTERS,
    zoo: Path | None = None,
) -> dict[str, Any]:
    """Run the scenario as two demo users of the gateway (``requesters``); returns what
    happened (task id, CID, reputations, allocation)."""
    req1, req2 = DemoUser(url, requesters[0]), DemoUser(url, requesters[1])
    anon = Gateway(url)
    report: dict[str, Any] = {"url": url}

    _register_requester(req1)
    say(f"requester {req1.address} registered")
    workers = wait_for(
        "three registered workers",
        lambda: anon.get("/workers")["data"],
        lambda d: len(d) >= 3,
        timeout=120,
    )
    say("workers: " + ", ".join(f"{w['address']} ({w.get('cpu_cores')} cores)" for w in workers))
    rep_before = {w["address"]: w.get("reputation") for w in workers}

    t0 = time.monotonic()
    created = write(
        req1,
        "POST",
        "/tasks",
        {
            "env": SCENARIO_ENV,
            "observation": {"kind": "odmtl", "window": 3},
            "budget": {"steps": steps, "minutes": 2},
            "seed": 7,
            "num_workers": 1,
            "payment_wei": 10**16,
            "deadline_s": 3600,
            "domain": 0,
        },
    )
    task_id = created["task_id"]
    report.update(task_id=task_id, spec_cid=created["spec_cid"], offered=created["offered"])
    say(
        f"task {task_id} submitted (spec {created['spec_cid']}); the chain offered it to "
        f"{created['offered']}"
    )
    if not created["offered"]:
        raise RuntimeError("the chain recruited nobody: are the workers registered and eligible?")

    seen = 0

    def show_progress(d: dict[str, Any]) -> dict[str, Any]:
        nonlocal seen
        for p in d.get("progress", [])[seen:]:
            say(
                f"  progress {p['worker'][:10]} step {p['step']:>6} success "
                f"{_figure(p.get('success'), '.2f')} time {_figure(p.get('time'), '.1f')}"
            )
        seen = len(d.get("progress", []))
        return d

    detail = wait_for(
        f"an outcome of task {task_id}",
        lambda: show_progress(anon.get(f"/tasks/{task_id}")),
        lambda d: bool(d.get("outcomes")),
        timeout=timeout,
        every=0.5,
    )
    outcome = detail["outcomes"][0]
    worker, cid = outcome["worker"], outcome["cid"]
    report.update(
        worker=worker,
        cid=cid,
        progress_points=len(detail.get("progress", [])),
        seconds_to_outcome=time.monotonic() - t0,
    )
    say(
        f"worker {worker} submitted model {cid} (manifest) after "
        f"{report['seconds_to_outcome']:.1f} s and {report['progress_points']} progress points"
    )

    after = _accept_outcome(req1, anon, task_id, worker, review=5)
    report.update(reputation_before=rep_before.get(worker), reputation_after=after["reputation"])
    say(f"review 5/5: reputation of {worker} {rep_before.get(worker)} -> {after['reputation']}")

    key_file = next(
        (
            k
            for k in (data_dir / "keys").glob("*.key")
            if Account.from_key(k.read_text().strip()).address == worker
        ),
        None,
    )
    if key_file is None:
        raise RuntimeError(f"no key file of worker {worker} under {data_dir / 'keys'}")
    owner = Gateway(url, Account.from_key(key_file.read_text().strip()))
    write(
        owner,
        "POST",
        "/models",
        {
            "cid": cid,
            "description": f"trained for task {task_id}",
            "domain": 0,
            "env": SCENARIO_ENV,
        },
    )
    listed = wait_for(
        "the model in the listing",
        lambda: anon.get("/models")["data"],
        lambda d: any(m["cid"] == cid for m in d),
        timeout=30,
    )
    model = next(m for m in listed if m["cid"] == cid)
    report["model_id"] = model["id"]
    say(f"model {model['id']} listed: owner {model['owner']}, cid {cid}")

    _register_requester(req2)
    alloc = write(
        req2, "POST", "/models/requests", {"domain": 0, "env": SCENARIO_ENV, "num_models": 1}
    )
    report.update(alloc_id=alloc["alloc_id"], allocated=[m["cid"] for m in alloc["models"]])
    say(
        f"requester {req2.address} asked for experts: allocation {alloc['alloc_id']} -> "
        f"{report['allocated']}"
    )
    if cid not in report["allocated"]:
        raise RuntimeError(f"the expert request did not return the trained model {cid}")
    report["medc"] = _medc_task(req2, anon, alloc["alloc_id"], model["id"], steps, timeout, say)
    if zoo is not None and zoo.is_dir():
        report["zoo"] = _share_zoo(zoo, url, data_dir, [w["address"] for w in workers], say)
    for g in (req1, req2, anon, owner):
        g.close()
    return report


def detail_updates(card: dict[str, Any]) -> Any:
    """The run's last update from the card's curve (the kept policy's card says when it was
    chosen; its curve is the whole run's)."""
    return (card.get("curve") or {}).get("updates", "?")


def _accept_outcome(
    req: Gateway, anon: Gateway, task_id: int, worker: str, *, review: int
) -> dict[str, Any]:
    """The requester accepts ``worker``'s outcome of ``task_id`` with ``review`` stars; the
    worker as the index shows it once the review is in. The accepted review is what counts
    the task as completed (E of Eq. 18), so this waits for the review in the counters, not for
    any change of reputation (the offer alone moved it already)."""
    rated = anon.get(f"/workers/{worker}")["counters"]["rating_count"]
    write(req, "POST", f"/tasks/{task_id}/reviews",
          {"worker": worker, "review": review, "accepted": True})
    return wait_for(
        "the review in the worker's counters",
        lambda: anon.get(f"/workers/{worker}"),
        lambda w: w["counters"]["rating_count"] > rated,
        timeout=30,
    )


def _medc_task(
    req: Gateway,
    anon: Gateway,
    alloc_id: int,
    model_id: int,
    steps: int,
    timeout: float,
    say: Callable[[str], None],
) -> dict[str, Any]:
    """Train a task guided by the allocation's models (MEDC), read which experts the outcome's
    card says were used, accept the outcome and review the expert (MMC updateModelRep,
    Eq. 10-11)."""
    created = write(
        req,
        "POST",
        "/tasks",
        {
            "env": SCENARIO_ENV,
            "observation": {"kind": "odmtl", "window": 3},
            "budget": {"steps": steps, "minutes": 2},
            "seed": 8,
            "num_workers": 1,
            "payment_wei": 10**16,
            "deadline_s": 3600,
            "domain": 0,
            "expert_allocation": alloc_id,
            "algorithm": {"demonstration": {"rate": 0.5}},
            "selection": {"keep_best": "time", "eval_every": 2},  # deliver the best evaluated
        },
    )
    task_id = created["task_id"]
    say(
        f"task {task_id}: MEDC with the experts of allocation {alloc_id}, offered to "
        f"{created['offered']}"
    )
    detail = wait_for(
        f"an outcome of MEDC task {task_id}",
        lambda: anon.get(f"/tasks/{task_id}"),
        lambda d: bool(d.get("outcomes")),
        timeout=timeout,
        every=0.5,
    )
    worker = detail["outcomes"][0]["worker"]
    card = req.get(
        f"/models/outcomes/{task_id}/{worker}/download", auth=True, params={"file": "model.json"}
    )
    used = card["training"]["experts"]["experts"]
    say(
        "  the outcome's card lists its experts: "
        + ", ".join(
            f"{e['ref']} (qos {e['qos']:.3f}, guided {e['episodes']} episodes)" for e in used
        )
    )
    selected = card["training"]["selected"]
    say(
        f"  delivered: the best evaluated policy by time, update {selected['update']} of "
        f"{detail_updates(card)} (mean time {selected['eval_time']:.1f} steps on "
        f"{selected['eval_episodes']} evaluation episodes)"
    )
    _accept_outcome(req, anon, task_id, worker, review=5)
    say(f"  outcome of {worker} accepted, 5/5")
    # the worker's trial of each expert on the task after the run: the review's evidence
    trials = {t["ref"]: t for t in card["training"]["experts"].get("review", {}).get("experts", [])}
    trial = trials.get(used[0]["ref"])
    if trial is None:
        raise RuntimeError(f"task {task_id}: the outcome's card has no trial of its expert")
    review = trial["suggested_review"]
    say(
        f"  the worker's trial of the expert on the task: success {trial['success']:.0%}, "
        f"time {trial['time']:.1f} steps ({trial['time_vs_oracle']:.2f}x the oracle): "
        f"suggests {review}/5"
    )
    before = anon.get(f"/models/{model_id}")["reputation"]
    write(req, "POST", f"/models/requests/{alloc_id}/reviews",
          {"model_id": model_id, "review": review})
    wait_for(
        "the expert's review to be indexed",
        lambda: anon.get(f"/tasks/{task_id}"),
        lambda d: any(x.get("review") is not None for x in d.get("experts", [])),
        timeout=30,
    )
    after = anon.get(f"/models/{model_id}")["reputation"]
    say(f"review {review}/5 of expert model {model_id}, as suggested: reputation {before} -> "
        f"{after}")
    return {
        "task_id": task_id,
        "worker": worker,
        "cid": detail["outcomes"][0]["cid"],
        "experts": [{"ref": e["ref"], "episodes": e["episodes"]} for e in used],
        "selected": {k: selected[k] for k in ("by", "update", "global_step", "eval_time")},
        "expert_review": review,
        "expert_trial": trial,
        "expert_reputation": [before, after],
    }


def _share_zoo(
    zoo: Path, url: str, data_dir: Path, workers: list[str], say: Callable[[str], None]
) -> dict[str, str]:
    """Upload each zoo model (weights + card) to the platform's store and list it on chain,
    the models spread over the workers. An owner lists at most ``maxModelsPerOwner`` models
    (MMC): when every owner is full, the zoo gets a publisher account of its own
    (:func:`_zoo_publisher`), so the whole zoo is listed however large it grows."""
    from backend.store import make_store
    from backend.store.bundle import upload_model

    store = make_store(data_dir / "ipfs")  # the embedded platform's block store (drlaas up)
    keys = {}
    for k in sorted((data_dir / "keys").glob("*.key")):
        acct = Account.from_key(k.read_text().strip())
        if acct.address in workers:
            keys[acct.address] = acct
    owners = [Gateway(url, keys[a]) for a in workers if a in keys]
    if not owners:
        raise RuntimeError(f"no worker key files under {data_dir / 'keys'}")
    full: set[str] = set()
    listed: dict[str, str] = {}
    policies = sorted(
        p.parent
        for p in zoo.glob("*/model.json")  # not the walls CAE
        if "kind" not in json.loads(p.read_text())
    )
    try:
        for i, model_dir in enumerate(policies):
            card = json.loads((model_dir / "model.json").read_text())
            zoo_card = card.get("zoo", {})
            body = {
                "cid": upload_model(store, model_dir),
                "description": f"zoo {model_dir.name}: {zoo_card.get('preset', card['model'])}",
                "domain": 0,
                "env": card["env"],
            }
            while True:
                free = [g for g in owners if g.address not in full]
                if not free:
                    owners.append(_zoo_publisher(url, data_dir, len(owners) - len(keys)))
                    continue
                owner = free[i % len(free)]
                try:
                    write(owner, "POST", "/models", body)  # answer or relayed receipt
                    break
                except GatewayError as exc:
                    rule = exc.detail.get("rule") if isinstance(exc.detail, dict) else None
                    if exc.status != 409 or rule != "models_owner_limit":
                        raise
                    full.add(owner.address)
            listed[model_dir.name] = body["cid"]
    finally:
        for g in owners:
            g.close()
    say(f"model zoo published: {len(listed)} models ({', '.join(listed)}) by {len(owners)} owners")
    return listed


def _zoo_publisher(url: str, data_dir: Path, n: int) -> Gateway:
    """A worker account that only lists zoo models (domain 0), its key in
    ``<data>/zoo-keys`` (not ``keys/``, whose accounts ``drlaas up`` runs as workers). It
    runs no daemon; the zoo is the scenario's last step, so no task is offered to it."""
    from workers.daemon.funding import ensure_gas
    from workers.daemon.keys import load_or_create_key

    gw = Gateway(url, load_or_create_key(data_dir / "zoo-keys" / f"publisher-{n}.key"))
    ensure_gas(gw)
    write(gw, "POST", "/users/workers", {"domains": [0], "cpu_cores": 1, "ram_gb": 1})
    return gw


def scenario_command(
    gateway: Annotated[
        str | None, typer.Option(envvar="DRLAAS_GATEWAY", help="URL of a running `drlaas up`")
    ] = None,
    data: Annotated[
        Path | None,
        typer.Option(
            help="with --gateway: its data directory (worker key files); without: a new, empty "
            "directory for the platform it starts (default <data>/demo-<time>)"
        ),
    ] = None,
    steps: Annotated[int, typer.Option(min=1000, help="training budget in env steps")] = 2000,
    workers: Annotated[int, typer.Option(min=3, help="workers when starting a platform")] = 3,
    as_json: Annotated[bool, typer.Option("--json")] = False,
) -> None:
    """Run the issue-4 scenario; without --gateway, start a platform for it and stop it after."""
    say = (lambda s: typer.echo(s, err=True)) if as_json else typer.echo
    settings = load_settings()
    if gateway:
        report = run_scenario(gateway, data or settings.data_dir, steps=steps, say=say)
    else:
        # a platform of its own starts from nothing: never reuse an earlier run's jobs or chain
        fresh = data or settings.data_dir / f"demo-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"
        if fresh.exists() and any(fresh.iterdir()):
            raise typer.BadParameter(f"{fresh} is not empty: give a new --data directory")
        with running_platform(workers=workers, data_dir=fresh) as p:
            p.wait_registered()
            say(f"platform up at {p.url}")
            # the platform it started: its store is this process's to write the zoo into
            zoo = ZOO_DIR if settings.ipfs_service.embedded else None
            report = run_scenario(p.url, p.data_dir, steps=steps, say=say, zoo=zoo)
    if as_json:
        typer.echo(json.dumps(report, indent=1, default=str))
    else:
        typer.echo("scenario completed")


def _figure(value: Any, spec: str) -> str:
    """A curve point's figure for a person: rounded, '-' when the point has none."""
    return format(value, spec) if isinstance(value, int | float) else "-"
