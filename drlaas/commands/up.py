"""``drlaas up``: the whole platform embedded on one machine.

In this process: the gateway (uvicorn in a thread) hosting the embedded chain with the contracts
deployed, its ``/rpc``, the indexer and the content store. As child processes: N worker daemons
(``python -m workers.daemon.command``), each with its own key file, data directory and Celery
queue ``worker.<address>`` on the embedded broker. Development conveniences, embedded chain
only: every worker key is funded from the deployer account, and the TMC is told to accept GPU
series 0 (CPU-only machines like this one). Ctrl-C or SIGTERM stops the workers (warm shutdown,
SIGKILL after a grace period), then the gateway.
"""

from __future__ import annotations

import inspect
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import typer

log = logging.getLogger(__name__)

REPO = Path(__file__).resolve().parents[2]
WORKER_FUNDS_WEI = 100 * 10**18
STOP_GRACE_S = 15.0


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


@dataclass
class WorkerProc:
    address: str
    key: Path
    log: Path
    proc: subprocess.Popen[bytes]


@dataclass
class RunningPlatform:
    """Handles on a started platform (see :func:`running_platform`)."""

    url: str
    settings: Any
    app: Any
    data_dir: Path
    workers: list[WorkerProc] = field(default_factory=list)
    _env: dict[str, str] = field(default_factory=dict)
    _args: list[str] = field(default_factory=list)

    @property
    def chain(self) -> Any:
        return self.app.state.chain

    def start_worker(self, i: int) -> WorkerProc:
        """Start (or restart) worker ``i`` with its key file ``<data>/keys/worker<i>.key``."""
        from workers.daemon.keys import load_or_create_key

        key = self.data_dir / "keys" / f"worker{i}.key"
        account = load_or_create_key(key)
        fund(self.chain, account.address)
        logf = self.data_dir / "logs" / f"worker{i}.log"
        logf.parent.mkdir(parents=True, exist_ok=True)
        cmd = [
            sys.executable,
            "-m",
            "workers.daemon.command",
            "--key",
            str(key),
            "--gateway",
            self.url,
            *self._args,
        ]
        proc = subprocess.Popen(
            cmd,
            cwd=REPO,
            env=self._env,
            stdout=logf.open("ab"),
            stderr=subprocess.STDOUT,
            start_new_session=True,
            preexec_fn=_die_with_parent,
        )
        wp = WorkerProc(account.address, key, logf, proc)
        if i < len(self.workers):
            self.workers[i] = wp
        else:
            self.workers.append(wp)
        return wp

    def wait_registered(self, timeout: float = 120.0) -> None:
        """Until every worker's record is on chain (the daemon registers before consuming)."""
        umc = self.chain.platform.umc
        deadline = time.monotonic() + timeout
        for w in self.workers:
            while self.chain.call(umc, "workerId", w.address) == 0:
                if w.proc.poll() is not None:
                    raise RuntimeError(
                        f"worker {w.address} exited ({w.proc.returncode}); "
                        f"log:\n{w.log.read_text()[-3000:]}"
                    )
                if time.monotonic() > deadline:
                    raise TimeoutError(f"worker {w.address} did not register; log {w.log}")
                time.sleep(0.1)


def _die_with_parent() -> None:
    """In the forked child: be killed when ``drlaas up`` dies (even by kill -9), so no daemon
    outlives the platform it was started for and a restarted ``drlaas up`` never runs two
    daemons of one worker. SIGKILL, not SIGTERM: Celery's warm shutdown would finish the whole
    training job first; the unacknowledged job is redelivered and resumes from its checkpoint.
    (Linux prctl PR_SET_PDEATHSIG; elsewhere the daemon's lock file still stops a second copy.)"""
    if sys.platform != "linux":
        return
    import ctypes

    PR_SET_PDEATHSIG = 1
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def fund(chain: Any, address: str, amount: int = WORKER_FUNDS_WEI) -> None:
    """Send gas money from the deployer to ``address`` (development only: the gateway holds
    the deployer's key on the embedded chain, or a dev node's first account)."""
    if chain.platform.admin not in chain.chain._keys:
        return
    w3 = chain.chain.w3
    with chain.lock:
        if w3.eth.get_balance(address) >= amount // 2:
            return
        admin = chain.platform.admin
        base = w3.eth.get_block("latest").get("baseFeePerGas", 0) or 0
        tx = {
            "to": address,
            "value": amount,
            "gas": 21_000,
            "chainId": chain.chain.chain_id,
            "nonce": w3.eth.get_transaction_count(admin, "pending"),
            "maxFeePerGas": 2 * base + 1,
            "maxPriorityFeePerGas": 0,
        }
        signed = chain.chain._keys[admin].sign_transaction(tx)
        w3.eth.wait_for_transaction_receipt(w3.eth.send_raw_transaction(signed.raw_transaction))


def accept_cpu_only(chain: Any) -> None:
    """Let the TMC recruit workers without a GPU (series 0), when we hold the admin key."""
    if chain.platform.admin not in chain.chain._keys:
        return
    tmc = chain.platform.tmc
    with chain.lock:
        if not int(tmc.call("acceptedGpus")) & 1:
            tmc.transact("setGpuSeries", 0, True, sender=chain.platform.admin)


def build_gateway(settings: Any) -> Any:
    """The gateway app with the indexer's ``on_offer`` hook enqueuing the daemon's job."""
    from backend.api.main import create_app
    from workers.daemon.tasks import make_on_offer

    hook = make_on_offer(settings)
    hook.warm()  # type: ignore[attr-defined]
    if "on_offer" in inspect.signature(create_app).parameters:
        app = create_app(settings, on_offer=hook)
    else:
        app = create_app(settings)
    app.state.on_offer = hook
    return app


def _install_hook(app: Any) -> None:
    indexer = getattr(app.state, "indexer", None)
    if indexer is not None and getattr(indexer, "on_offer", None) is not app.state.on_offer:
        indexer.on_offer = app.state.on_offer


@contextmanager
def running_platform(
    workers: int = 3,
    port: int = 0,
    host: str = "127.0.0.1",
    data_dir: Path | None = None,
    worker_args: list[str] | None = None,
    env: dict[str, str] | None = None,
) -> Iterator[RunningPlatform]:
    """Start gateway + N workers; stop everything on exit (also on errors)."""
    import uvicorn

    from backend.api.http_limits import BoundedHttpToolsProtocol
    from backend.settings import load_settings
    from workers.daemon.links import Deployment, write_deployment

    port = port or free_port(host)
    overrides = {"auth_domain": f"{host}:{port}", "auth_uri": f"http://{host}:{port}"}
    if data_dir is not None:
        overrides["data_dir"] = str(data_dir)
    settings = load_settings(**overrides)
    data = settings.data_dir
    data.mkdir(parents=True, exist_ok=True)
    app = build_gateway(settings)
    server = uvicorn.Server(
        uvicorn.Config(
            app,
            host=host,
            port=port,
            log_level="warning",
            lifespan="on",
            http=BoundedHttpToolsProtocol,  # a request head of any size was buffered whole
            # json: uvicorn's loggers go through the root handler (one JSON object per line)
            **({"log_config": None} if settings.log_format == "json" else {}),
        )
    )
    thread = threading.Thread(target=server.run, name="gateway", daemon=True)
    thread.start()
    url = f"http://{host}:{port}"
    deadline = time.monotonic() + 120
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError("the gateway did not start (see the log above)")
        time.sleep(0.05)
    _install_hook(app)
    running = RunningPlatform(url, settings, app, data)
    child_env = dict(os.environ)  # DRLAAS_* choices (e.g. DRLAAS_CONTRACTS) pass through
    child_env.update(
        {
            "DRLAAS_DATA_DIR": str(data),
            "DRLAAS_CHAIN": settings.chain,
            "DRLAAS_IPFS": settings.ipfs,
            "DRLAAS_BROKER": settings.broker,
            "DRLAAS_GATEWAY": url,
            "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]).rstrip(
                os.pathsep
            ),
            "OMP_NUM_THREADS": "1",
            **(env or {}),
        }
    )
    running._env = child_env
    running._args = list(worker_args or [])
    try:
        if getattr(app.state, "chain", None) is not None:
            accept_cpu_only(app.state.chain)
            addresses = app.state.chain.addresses()
            write_deployment(
                data / "deployment.json",
                Deployment.from_dict(addresses),
                f"{url}/rpc" if settings.chain == "embedded" else settings.chain,
            )
        for i in range(workers):
            running.start_worker(i)
        yield running
    finally:
        stop_workers(running.workers)
        server.should_exit = True
        thread.join(timeout=30)


def stop_workers(workers: list[WorkerProc], grace: float = STOP_GRACE_S) -> None:
    for w in workers:
        if w.proc.poll() is None:
            w.proc.send_signal(signal.SIGTERM)  # Celery warm shutdown
    deadline = time.monotonic() + grace
    for w in workers:
        try:
            w.proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            w.proc.kill()
            w.proc.wait(timeout=10)


def port_free(host: str, port: int) -> bool:
    """Whether the gateway could listen on ``host:port`` now (bound as uvicorn binds it, with
    SO_REUSEADDR, so a port in TIME_WAIT counts as free)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def up_command(
    workers: Annotated[int, typer.Option(min=0, max=32, help="local worker daemons")] = 3,
    port: Annotated[int, typer.Option(min=0, max=65535, help="gateway port (0 = a free one)")] = 0,
    host: Annotated[str, typer.Option(help="interface to listen on")] = "127.0.0.1",
    data: Annotated[
        Path | None, typer.Option(help="data directory (default DRLAAS_DATA_DIR)")
    ] = None,
) -> None:
    """Start the whole platform on this machine; Ctrl-C stops it."""
    from backend.observability.logs import configure_logging
    from backend.settings import load_settings

    settings = load_settings()
    configure_logging(settings.log_format)  # DRLAAS_LOG_FORMAT=json|text
    # a fresh data directory's migrations are a dozen INFO lines before the banner
    logging.getLogger("alembic").setLevel(logging.WARNING)
    if port and not port_free(host, port):  # before a data directory or a chain is made
        typer.echo(
            f"error: {host}:{port} is in use (another `drlaas up`?): stop it, or choose another "
            "port with --port (0: a free one)",
            err=True,
        )
        raise typer.Exit(1)
    if settings.demo_keys_allowed and host not in ("127.0.0.1", "::1", "localhost"):
        typer.echo(
            f"warning: --host {host} serves the development platform beyond this machine: "
            "workers join without the consortium's approval, the faucet funds any new key, and "
            "the whole platform (chain, store, broker) is this one process. For a network, deploy "
            "the consortium chain and DRLAAS_MODE=production (README, 'From one machine to "
            "many').",
            err=True,
        )
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    with running_platform(workers=workers, port=port, host=host, data_dir=data) as p:
        p.wait_registered()
        typer.echo(
            json.dumps(
                {
                    "url": p.url,
                    "rpc": f"{p.url}/rpc",
                    "data_dir": str(p.data_dir),
                    "workers": [w.address for w in p.workers],
                }
            )
        )
        typer.echo(
            f"DRLaaS is up at {p.url} (web UI), API {p.url}/api/docs; Ctrl-C to stop", err=True
        )
        while not stop.wait(0.5):
            for i, w in enumerate(p.workers):
                if w.proc.poll() is not None:
                    typer.echo(
                        f"worker {w.address} exited ({w.proc.returncode}); restarting", err=True
                    )
                    p.start_worker(i)
        typer.echo("stopping...", err=True)
    typer.echo("stopped", err=True)


def main() -> None:
    typer.run(up_command)


if __name__ == "__main__":
    main()
