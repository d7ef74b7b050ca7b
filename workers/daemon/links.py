"""A worker's connections: the chain (signing with its own key only), the content store and the
contract addresses.

In embedded mode the gateway hosts the chain and serves it at ``<gateway>/rpc`` (platform.md),
so a daemon uses :meth:`Chain.rpc` either way: ``DRLAAS_CHAIN`` when it is a node URL, else the
gateway's ``/rpc``. Contract addresses come from, in order: ``DRLAAS_CONTRACTS`` (JSON or the
path of a JSON file), the gateway (``GET /api/chain/contracts``), ``<data>/deployment.json``.
What the gateway names is pinned on first use (:func:`pinned_platform`): later it must name the
same.

A worker needs no ``DRLAAS_DATA_DIR`` (:func:`worker_settings`): its own files go to the per-user
``~/.drlaas``, and when the gateway's broker and store are embedded (on this machine) it opens
the gateway's, whose location the gateway tells loopback clients (``GET /api/local/services``).
"""

from __future__ import annotations

import ipaddress
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
from eth_account.signers.local import LocalAccount

from backend.chain.addresses import checksum
from backend.chain.client import Chain
from backend.chain.pins import read_pins, write_pin
from backend.chain.platform import Platform, connect_platform
from backend.httpbounds import bounded_get
from backend.settings import Settings, load_settings
from backend.store import ContentStore, make_store

DEPLOYMENT_FILE = "deployment.json"
PIN_FILE = "platform.json"
"""In a worker's own directory: the deployments its gateways named on first use."""
#: The gateway of ``drlaas up --port 8000`` on this machine: where an embedded chain lives when
#: no --gateway / DRLAAS_GATEWAY is given.
LOCAL_GATEWAY = "http://127.0.0.1:8000"
#: A worker's own data directory when DRLAAS_DATA_DIR is not set (job directories, keys).
USER_DATA_DIR = Path("~/.drlaas")
_NAMES = {"umc": "UsersManager", "tmc": "TasksManager", "mmc": "ModelsManager"}


@dataclass(frozen=True)
class Deployment:
    """Addresses of the three platform contracts."""

    umc: str
    tmc: str
    mmc: str

    def to_dict(self) -> dict[str, str]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Deployment:
        """Accepts ``{umc, tmc, mmc}`` or contract names (``UsersManager``...), possibly under
        a ``contracts`` key; ValueError naming what is wrong with any other document."""
        if not isinstance(d, dict):
            raise ValueError(f"deployment: not a JSON object but {type(d).__name__}")
        if isinstance(d.get("contracts"), dict):
            d = d["contracts"]
        out = {}
        for short, name in _NAMES.items():
            v = d.get(short) or d.get(name)
            if isinstance(v, dict):
                v = v.get("address")
            if not isinstance(v, str) or not v.startswith("0x"):
                raise ValueError(f"deployment: no address for {name} ({short}) in {sorted(d)}")
            out[short] = v
        return cls(**out)

    @classmethod
    def of(cls, platform: Platform) -> Deployment:
        return cls(platform.umc.address, platform.tmc.address, platform.mmc.address)


def write_deployment(path: str | Path, deployment: Deployment, chain_url: str = "") -> None:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps({**deployment.to_dict(), "chain": chain_url}, indent=1))


def find_deployment(
    settings: Settings, gateway: str | None
) -> tuple[Deployment, int | None, bool]:
    """(the contract addresses, the chain id their source names if it names one, whether the
    gateway named them): see the module docstring; the error lists what was tried."""
    tried = []
    env = os.environ.get("DRLAAS_CONTRACTS", "").strip()
    if env:
        doc = json.loads(env if env.startswith("{") else Path(env).read_text())
        return Deployment.from_dict(doc), _positive_int(doc.get("chain_id")), False
    tried.append("DRLAAS_CONTRACTS (unset)")
    if gateway:
        for path in ("/api/chain/contracts",):
            try:
                r = bounded_get(gateway.rstrip("/") + path, timeout=10)  # bounded answer
                if r.is_success:
                    doc = r.json()
                    return Deployment.from_dict(doc), _positive_int(doc.get("chain_id")), True
                tried.append(f"GET {path} -> {r.status_code}")
            except (httpx.HTTPError, ValueError) as exc:
                tried.append(f"GET {path}: {exc}")
    f = settings.data_dir / DEPLOYMENT_FILE
    if f.is_file():
        doc = json.loads(f.read_text())
        return Deployment.from_dict(doc), _positive_int(doc.get("chain_id")), False
    tried.append(f"{f} (missing)")
    raise SetupError("cannot find the contract addresses; tried: " + "; ".join(tried))


def _positive_int(value: Any) -> int | None:
    ok = isinstance(value, int) and not isinstance(value, bool) and value > 0
    return value if ok else None


class SetupError(RuntimeError):
    """A daemon or client cannot start with these settings: the message says what to change
    (the CLI prints it as one line, without a traceback)."""


class DeploymentChanged(SetupError):
    """The gateway names another deployment than the one this worker pinned on first use."""


@dataclass(frozen=True)
class PinnedPlatform:
    """What a daemon signs for: the contracts and the chain id it must find at the node."""

    deployment: Deployment
    chain_id: int | None
    """``None``: unknown until the node is asked (the chain client's own pins still hold)."""
    pin_file: Path | None
    """Where to record the node's chain id after the first connection (``None``: nothing to
    record, the deployment came from the operator or is already pinned)."""


def pinned_platform(settings: Settings, gateway: str | None, pin_file: Path) -> PinnedPlatform:
    """The deployment a daemon works for. Contracts named by the operator (``DRLAAS_CONTRACTS``,
    ``<data>/deployment.json``) are taken as they are. Contracts learnt from the gateway are
    pinned on first use, with the chain id, in ``pin_file`` (:mod:`backend.chain.pins`): a
    gateway that later names other contracts or another chain is refused
    (:class:`DeploymentChanged`), so a hostile or hijacked gateway cannot have the worker sign
    for its own contracts or for another chain."""
    deployment, chain_id, from_gateway = find_deployment(settings, gateway)
    if not from_gateway or not gateway:
        return PinnedPlatform(deployment, chain_id, None)
    url = gateway.rstrip("/")
    entry = read_pins(pin_file).get(url)
    if entry is None:
        return PinnedPlatform(deployment, chain_id, pin_file)
    pinned_chain = entry.get("chain_id") if isinstance(entry, dict) else None
    pinned = entry.get("contracts") if isinstance(entry, dict) else None
    if _positive_int(pinned_chain) is None or not isinstance(pinned, dict):
        raise ValueError(f"{pin_file}: the {url!r} entry is not {{chain_id, contracts}}; remove "
                         "it to pin the gateway's deployment again")
    named = pin_contracts(deployment)
    if pinned != named or (chain_id is not None and pinned_chain != chain_id):
        raise DeploymentChanged(
            f"the gateway {url} names chain {chain_id} and contracts {_show(named)}, but this "
            f"worker pinned chain {pinned_chain} and contracts {_show(pinned)} for it on first "
            f"use, in "
            f"{pin_file}: refusing to sign for another deployment (a hostile or hijacked "
            f"gateway, or a redeployed platform). If the platform was really redeployed, run "
            f"`drlaas pin forget --gateway {url} --key <the worker's key file>` (or remove the "
            f"{url!r} entry of {pin_file}), or set DRLAAS_CONTRACTS and DRLAAS_CHAIN_ID to the "
            f"deployment you trust"
        )
    return PinnedPlatform(deployment, int(pinned_chain), None)


def _show(contracts: dict[str, Any]) -> str:
    """Contracts in one order (``name=address, ...``), so two lists compare by eye."""
    return ", ".join(f"{name}={contracts[name]}" for name in sorted(contracts))


def pin_contracts(deployment: Deployment) -> dict[str, str]:
    """{contract name: checksummed address}, as pin files keep them."""
    return {_NAMES[short]: checksum(a) for short, a in deployment.to_dict().items()}


def record_pin(pin_file: Path, gateway: str, deployment: Deployment, chain_id: int) -> None:
    """Pin ``gateway``'s deployment and the chain id its node reported."""
    write_pin(pin_file, gateway.rstrip("/"), chain_id, pin_contracts(deployment))


def default_gateway() -> str | None:
    """:data:`LOCAL_GATEWAY` when the chain is embedded (it lives in a gateway), else ``None``
    (a real node needs no gateway)."""
    return LOCAL_GATEWAY if load_settings().chain_service.embedded else None


def default_worker_dir(address: str) -> Path:
    """Where ``drlaas worker run`` without ``--data`` keeps the worker's files (its jobs, its
    pin file): ``<DRLAAS_DATA_DIR or ~/.drlaas>/workers/<address>``."""
    own = (load_settings().data_dir if os.environ.get("DRLAAS_DATA_DIR")
           else USER_DATA_DIR.expanduser().resolve())
    return own / "workers" / address


def worker_settings(gateway: str | None) -> tuple[Settings, Path]:
    """(settings for the shared services, the worker's own data directory).

    With ``DRLAAS_DATA_DIR`` set both are that directory (``drlaas up`` starts its workers so).
    Without it the worker's own directory is ``~/.drlaas``, and when its broker or store is
    ``embedded`` the gateway's embedded ones are used (same machine; an error says so if the
    gateway does not tell where they are)."""
    if os.environ.get("DRLAAS_DATA_DIR"):
        settings = load_settings()
        return settings, settings.data_dir
    own = USER_DATA_DIR.expanduser().resolve()
    settings = load_settings(data_dir=str(own))
    if not gateway or not (settings.broker_service.embedded or settings.ipfs_service.embedded):
        return settings, own
    if not is_loopback_url(gateway):
        raise SetupError(
            f"DRLAAS_BROKER / DRLAAS_IPFS are 'embedded', which means the gateway's own files on "
            f"this machine, but the gateway {gateway} is not a loopback address (only a gateway "
            f"on this machine is asked where they are); set DRLAAS_BROKER and DRLAAS_IPFS to "
            f"the platform's broker and IPFS URLs"
        )
    try:
        r = bounded_get(gateway.rstrip("/") + "/api/local/services", timeout=10)
        doc = r.json() if r.is_success else None
    except httpx.TransportError as exc:  # nothing listens there: not a question of settings
        raise SetupError(
            f"cannot reach the gateway {gateway} ({exc}): is the platform running "
            f"(`drlaas up`), and is --gateway / DRLAAS_GATEWAY its URL?"
        ) from None
    except (httpx.HTTPError, ValueError):
        doc = None
    if not isinstance(doc, dict) or not isinstance(doc.get("data_dir"), str):
        raise SetupError(
            f"DRLAAS_BROKER / DRLAAS_IPFS are 'embedded' but the gateway {gateway} does not say "
            f"where its embedded services are (it must run on this machine in development "
            f"mode); set DRLAAS_BROKER and DRLAAS_IPFS to the platform's broker and IPFS URLs"
        )
    overrides: dict[str, Any] = {}
    if settings.broker == "embedded" and doc.get("broker_embedded"):
        overrides["data_dir"] = _local_dir(gateway, "data_dir", doc["data_dir"])
    if settings.ipfs == "embedded" and doc.get("ipfs_dir"):
        overrides["ipfs"] = "embedded:" + _local_dir(gateway, "ipfs_dir", doc["ipfs_dir"])
    return load_settings(**{"data_dir": str(own), **overrides}), own


def is_loopback_url(url: str) -> bool:
    """Whether ``url``'s host is this machine by its literal name: ``localhost`` or a
    loopback IP address (127.0.0.0/8, ::1). Names are not resolved."""
    try:
        host = (urlsplit(url).hostname or "").lower()
    except ValueError:
        return False
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _local_dir(gateway: str, name: str, value: Any) -> str:
    """A directory named by a loopback gateway's ``/api/local/services``: an absolute path
    with no ``..`` (SetupError naming the field otherwise)."""
    if (
        not isinstance(value, str)
        or not value
        or "\0" in value
        or not Path(value).is_absolute()
        or ".." in Path(value).parts
    ):
        raise SetupError(
            f"the gateway {gateway} names {name} {value!r} for its embedded services: not an "
            f"absolute path without '..'; set DRLAAS_BROKER and DRLAAS_IPFS instead"
        )
    return value


def chain_url(settings: Settings, gateway: str | None) -> str:
    """The JSON-RPC endpoint a daemon or CLI uses: the node, or the gateway's ``/rpc``."""
    if not settings.chain_service.embedded:
        return settings.chain
    if not gateway:
        raise ValueError(
            "DRLAAS_CHAIN=embedded: the chain lives in the gateway; give its URL "
            "(--gateway or DRLAAS_GATEWAY) so the daemon can reach <gateway>/rpc"
        )
    return gateway.rstrip("/") + "/rpc"


def connect_worker(
    url: str, account: LocalAccount, deployment: Deployment, chain_id: int | None = None
) -> Platform:
    """Typed UMC/TMC/MMC handles over ``url`` that can sign for ``account`` only (the
    platform's one :func:`~backend.chain.platform.connect_platform`, as the gateway attaches);
    the node must report ``chain_id`` when one is given (:class:`NodeRefused` otherwise)."""
    chain = Chain.rpc(url, private_keys=["0x" + bytes(account.key).hex()], chain_id=chain_id)
    names = {_NAMES[short]: address for short, address in deployment.to_dict().items()}
    return connect_platform(chain, names, admin=account.address)


def open_store(settings: Settings) -> ContentStore:
    svc = settings.ipfs_service
    return make_store(svc.url if svc.embedded else svc.url, default_dir=settings.data_dir / "ipfs")


def task_spec_cid(platform: Platform, task_id: int) -> str:
    """The task's on-chain description (its spec CID), from its ``TaskAdded`` event, decoded as
    the indexer decodes it: bytes that are not UTF-8 (anyone's own addTask may hold any) read
    as U+FFFD, so the spec is refused and the offer declined (web3's strict decoding raised,
    and the offer was never answered)."""
    tmc = platform.tmc
    topics = [tmc.contract.events.TaskAdded().topic, "0x" + task_id.to_bytes(32, "big").hex()]
    logs = [e for e in platform.chain.logs(tmc, topics=topics) if e.name == "TaskAdded"]
    if not logs:
        raise LookupError(f"task {task_id}: no TaskAdded event on the TMC {tmc.address}")
    return str(logs[0].args["description"])
