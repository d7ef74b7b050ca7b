"""``drlaas worker``: register this machine on chain and consume its offer queue.

On start the daemon measures CPU cores, RAM and GPU, registers its address as a worker (or
updates its capabilities when they changed), then runs a Celery worker on ``worker.<address>``
(solo pool, one job at a time: training already uses the cores it is given).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from workers.daemon.capabilities import Capabilities, measure

log = logging.getLogger(__name__)

#: A worker covers at most this many domains (UMC.MAX_WORKER_DOMAINS).
MAX_WORKER_DOMAINS = 4
#: Domains a worker serves when none are given (tasks default to domain 0).
DEFAULT_DOMAINS = "0-3"


def parse_domains(text: str) -> tuple[int, ...]:
    """'0,3,5-7' -> (0, 3, 5, 6, 7), codes the UMC accepts (0-47)."""
    out: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part:
                lo, hi = (int(x) for x in part.split("-"))
                out.update(range(lo, hi + 1))
            else:
                out.add(int(part))
        except ValueError:
            raise ValueError(
                f"--domains: expected codes like '0,3,5-7', got {text!r}"
            ) from None
    if not out or min(out) < 0 or max(out) > 47:
        raise ValueError(f"--domains: codes must be in 0-47, got {text!r}")
    return tuple(sorted(out))


def domains_option(text: str) -> tuple[int, ...]:
    """``--domains`` of ``worker run`` / ``worker register``: :func:`parse_domains`, 1 to
    :data:`MAX_WORKER_DOMAINS` codes, or a usage error naming the option. ``worker run``
    checked them after making the key, asking the faucet and taking the daemon's lock, and
    ended with a ValueError traceback (always for 'all', 48 codes)."""
    try:
        domains = parse_domains(text)
    except ValueError as exc:
        raise typer.BadParameter(str(exc).removeprefix("--domains: "),
                                 param_hint="--domains") from None
    if not 1 <= len(domains) <= MAX_WORKER_DOMAINS:
        raise typer.BadParameter(
            f"a worker covers 1 to {MAX_WORKER_DOMAINS} domains (the UMC's limit), got "
            f"{len(domains)} from {text!r}", param_hint="--domains")
    return domains


#: Log levels Celery takes for ``--loglevel``.
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL", "FATAL")


def register_worker(platform: Any, caps: Capabilities, domains: tuple[int, ...]) -> str:
    """Add the worker record (or update its capabilities); returns what was done. On a chain
    where registration needs a consortium admin's approval, the new worker is pending (it is
    offered nothing until approved); a removed worker cannot serve again."""
    if not 1 <= len(domains) <= MAX_WORKER_DOMAINS:
        raise ValueError(
            f"--domains: a worker covers 1 to {MAX_WORKER_DOMAINS} domains (the UMC's limit), "
            f"got {len(domains)}"
        )
    from backend.chain.platform import WorkerStatus

    umc, me = platform.umc, platform.admin
    if platform.chain.balance(me) == 0 and platform.chain.w3.eth.gas_price > 0:
        raise RuntimeError(
            f"worker {me} has no native currency for gas on this chain; fund it first "
            f"(`drlaas up` funds its local workers)"
        )
    if umc.call("workerId", me) == 0:
        umc.add_worker(me, domains, caps.cpu_cores, caps.ram_gb, caps.gpu_series)
        if umc.call("getWorker", me)[1] == WorkerStatus.PENDING:
            return "registered, pending a consortium admin's approval"
        return "registered"
    w = umc.call("getWorker", me)
    if w[1] == WorkerStatus.REMOVED:
        raise RuntimeError(f"worker {me} was removed from the platform; use another key")
    current = (int(w[3]), int(w[4]), int(w[2]))  # cpuCores, ramGb, gpuSeries
    if current != (caps.cpu_cores, caps.ram_gb, caps.gpu_series):
        if w[1] == WorkerStatus.PENDING and umc.call("approvalRequired"):
            # the admin approves the values it reviewed: they are frozen until it decides
            return (f"pending a consortium admin's approval of the capabilities registered "
                    f"({current[0]} cores, {current[1]} GB, GPU series {current[2]}); they "
                    f"can change once approved")
        umc.transact("updateCapabilities", caps.cpu_cores, caps.ram_gb, caps.gpu_series, sender=me)
        if umc.call("getWorker", me)[1] == WorkerStatus.PENDING:  # approval covers capabilities
            return "updated, pending a consortium admin's re-approval"
        return "updated"
    return "unchanged"


def worker_command(
    key: Annotated[
        Path, typer.Option("--key", help="key file of this worker (created if missing)")
    ],
    gateway: Annotated[
        str | None,
        typer.Option(
            envvar="DRLAAS_GATEWAY",
            help="gateway URL (hosts /rpc in embedded mode; default http://127.0.0.1:8000 then)",
        ),
    ] = None,
    domains: Annotated[
        str, typer.Option(help=f"domain codes served (up to {MAX_WORKER_DOMAINS}), e.g. '0,3,5-6'")
    ] = DEFAULT_DOMAINS,
    max_jobs: Annotated[int, typer.Option(min=1, help="jobs at once before declining offers")] = 1,
    checkpoint_every: Annotated[int, typer.Option(min=1, help="updates between checkpoints")] = 2,
    checkpoint_interval: Annotated[
        float, typer.Option(min=0, help="least seconds between checkpoints (0: by updates only)")
    ] = 30.0,
    data: Annotated[
        Path | None,
        typer.Option(
            help="job directory root (default $DRLAAS_DATA_DIR or ~/.drlaas, + /workers/<address>)"
        ),
    ] = None,
    loglevel: Annotated[str, typer.Option(help="Celery log level")] = "INFO",
    metrics_port: Annotated[
        int | None,
        typer.Option(
            min=0,
            max=65535,
            envvar="DRLAAS_WORKER_METRICS_PORT",
            help="serve Prometheus /metrics on this port",
        ),
    ] = None,
    metrics_host: Annotated[str, typer.Option(help="interface of the metrics port")] = "127.0.0.1",
) -> None:
    """Run a worker daemon: register on chain, then accept, train and submit offered tasks."""
    served = domains_option(domains)  # options first: nothing made or asked on a bad one
    if loglevel.upper() not in LOG_LEVELS:  # Celery refused it only after registering
        raise typer.BadParameter(
            f"{loglevel!r} is none of {', '.join(LOG_LEVELS)}", param_hint="--loglevel")
    from backend.celery_app import worker_queue
    from backend.chain.pins import chain_pinned_for
    from workers.daemon import job, tasks
    from workers.daemon.funding import ensure_gas
    from workers.daemon.gateway import Gateway
    from workers.daemon.keys import load_or_create_key
    from workers.daemon.links import PIN_FILE, default_gateway, worker_settings
    from workers.daemon.lock import hold_daemon_lock
    from workers.daemon.logs import configure_daemon_logging
    from workers.daemon.metrics import serve_worker_metrics
    from workers.daemon.offer_watch import poll_interval_from_env, start_watcher

    offer_poll_s = poll_interval_from_env()  # a bad DRLAAS_WORKER_OFFER_POLL_S fails at once
    logging.getLogger("httpx").setLevel(logging.WARNING)  # one line per progress point otherwise
    gateway = gateway or default_gateway()
    # the daemon's variables as the handler will read them, checked before the key is made,
    # the faucet asked or the worker registered (a bad DRLAAS_WORKER_MODEL_CACHE_BYTES failed
    # only after all that)
    tasks.worker_env({
        **os.environ, "DRLAAS_WORKER_KEY": str(key), "DRLAAS_WORKER_MAX_JOBS": str(max_jobs),
        "DRLAAS_WORKER_CHECKPOINT_EVERY": str(checkpoint_every),
        "DRLAAS_WORKER_CHECKPOINT_INTERVAL_S": str(checkpoint_interval),
        **({"DRLAAS_GATEWAY": gateway} if gateway else {}),
        "DRLAAS_WORKER_DATA": str(data) if data else "",  # else set below, to its default
    })
    settings, own_dir = worker_settings(gateway)
    configure_daemon_logging(settings.log_format)  # DRLAAS_LOG_FORMAT=json|text
    account = load_or_create_key(key)
    # the Celery app and the job runtime read these (same services as the gateway's)
    os.environ["DRLAAS_DATA_DIR"] = str(settings.data_dir)
    os.environ["DRLAAS_IPFS"] = settings.ipfs
    os.environ["DRLAAS_WORKER_KEY"] = str(key)
    os.environ["DRLAAS_WORKER_MAX_JOBS"] = str(max_jobs)
    os.environ["DRLAAS_WORKER_CHECKPOINT_EVERY"] = str(checkpoint_every)
    os.environ["DRLAAS_WORKER_CHECKPOINT_INTERVAL_S"] = str(checkpoint_interval)
    worker_dir = data or own_dir / "workers" / account.address
    if gateway:
        os.environ["DRLAAS_GATEWAY"] = gateway
        # this sign-in names the pinned chain too
        known_chain = chain_pinned_for(worker_dir / PIN_FILE, gateway.rstrip("/"))
        with Gateway(gateway, account, chain_id=known_chain) as gw:
            ensure_gas(gw)  # an empty key on the embedded demo chain: the faucet
    os.environ["DRLAAS_WORKER_DATA"] = str(worker_dir)
    from workers.daemon.app import app  # built from the environment set above

    handler = tasks.runtime_from_env(settings)
    lock = hold_daemon_lock(handler.data_dir)  # noqa: F841 - held until the process exits
    metrics = (serve_worker_metrics(handler, metrics_port, metrics_host)
               if metrics_port is not None else None)
    caps = measure()
    done = register_worker(handler.platform, caps, served)
    typer.echo(
        f"worker {account.address}: {done} on chain ({caps.cpu_cores} cores, "
        f"{caps.ram_gb} GB RAM, GPU series {caps.gpu_series}); queue "
        f"{worker_queue(account.address)}",
        err=True,
    )
    job.warm_up()
    tasks.set_runtime(handler)
    on_offer = tasks.make_on_offer(settings, app)
    recover_jobs(handler, on_offer)
    watcher = start_watcher(handler, on_offer, offer_poll_s)  # offers the broker did not deliver
    if metrics is not None and watcher is not None:
        metrics.watch(watcher)
    app.worker_main(
        [
            "worker",
            "--pool",
            "solo",
            "-Q",
            worker_queue(account.address),
            "-n",
            f"{account.address}@%h",
            "--without-heartbeat",
            "--without-gossip",
            "--without-mingle",
            "--loglevel",
            loglevel,
        ]
    )


#: Seconds between background retries of jobs whose recovery at start was deferred (doubling
#: up to RECOVERY_RETRY_MAX_S).
RECOVERY_RETRY_S = 30.0
RECOVERY_RETRY_MAX_S = 600.0


def recover_jobs(
    handler: Any, enqueue: Any, *, retry_s: float = RECOVERY_RETRY_S, background: bool = True
) -> threading.Thread | None:
    """Reconcile the job directories with the chain before consuming offers
    (``OfferHandler.recover``), and say what was done on stderr (Celery's logging is not set up
    yet). Never fatal: jobs whose recovery failed (the node still down, a damaged job) are
    named, and a daemon thread retries them (``recover(only=...)``) every ``retry_s`` seconds,
    doubling, until none is left, so a job in hand whose message the broker lost is queued
    again once the node is back, without another restart. Returns that thread, if any."""
    pending = _recover_once(handler, enqueue, None, "at start")
    if not pending or not background:
        return None

    def retry() -> None:
        left, wait = pending, retry_s
        while left:
            time.sleep(wait)
            left = _recover_once(handler, enqueue, left, "retried")
            wait = min(wait * 2, RECOVERY_RETRY_MAX_S)

    thread = threading.Thread(target=retry, name="job-recovery", daemon=True)
    thread.start()
    return thread


def _recover_once(handler: Any, enqueue: Any, only: set[int] | None, when: str) -> set[int]:
    """One ``recover`` pass, reported on stderr; the task ids left to retry (all of ``only``
    when the pass itself failed; an empty set when a whole scan failed before any job)."""
    try:
        done = handler.recover(enqueue, only=only)
    except Exception as exc:  # noqa: BLE001 - recovery never keeps a worker from serving
        typer.echo(f"job recovery {when} skipped: {type(exc).__name__}: {exc}", err=True)
        return set(only or ())
    summary = ", ".join(f"{what} {ids}" for what, ids in done.items() if ids)
    if summary:
        typer.echo(f"jobs recovered {when}: {summary}", err=True)
    return set(done.get("deferred", ()))


def open_worker(key: Path, gateway: str | None, data: Path | None) -> Any:
    """This worker's :class:`~workers.daemon.handler.OfferHandler` outside the daemon (the
    same services, chain identity and job directories as ``drlaas worker run`` with these
    options), for commands that act on the daemon's finished jobs."""
    from workers.daemon import tasks
    from workers.daemon.keys import load_key
    from workers.daemon.links import default_gateway, worker_settings

    gateway = gateway or default_gateway()
    settings, own_dir = worker_settings(gateway)
    account = load_key(key)
    os.environ["DRLAAS_WORKER_KEY"] = str(key)
    if gateway:
        os.environ["DRLAAS_GATEWAY"] = gateway
    os.environ["DRLAAS_WORKER_DATA"] = str(data or own_dir / "workers" / account.address)
    return tasks.runtime_from_env(settings)


def main() -> None:
    typer.run(worker_command)


if __name__ == "__main__":
    main()
