"""What a write command agrees to sign when a gateway answers 409 ``sign_locally``.

The gateway builds the unsigned transaction, but it is not trusted with the key: before
:func:`drlaas.commands.client.session.write` signs, :func:`check_tx` compares the transaction
with what the command meant (an :class:`Expect`), and refuses (:class:`TxRefused`, nothing
signed, nothing relayed) on any difference, naming the field and both values:

* ``data`` must decode, with the contracts' ABIs (``contracts/build``), to one of the calls the
  command expects (e.g. ``model review`` -> ``ModelsManager.updateModelRep``), and the arguments
  the command's own inputs determine must be those inputs (ids, reviews, CIDs, domains...);
* ``to`` must be the address of that function's contract and ``chainId`` the chain of the
  deployment, both pinned: from ``DRLAAS_CONTRACTS`` / ``DRLAAS_CHAIN_ID`` when set, else on
  first use (trust on first use, like ssh's known_hosts) from the gateway's
  ``GET /api/chain/contracts``, kept in ``<key file>.platform.json`` per gateway URL;
* ``value`` must be what the command pays (0 but for ``addTask``'s escrow and
  ``allocateModel``'s price x K), and ``gas`` / the fee per gas at most
  ``DRLAAS_TX_MAX_GAS`` (default 30,000,000) / ``DRLAAS_TX_MAX_FEE_PER_GAS_WEI`` (default
  100 gwei), the caps the chain client signs under too (``backend.settings``);
* only the fields of a legacy (type 0) or EIP-1559 (type 2) transaction are accepted.

The expectation of each gateway route the CLI writes to is in :func:`expect_request` (the
commands pass the one of their request; a caller that passes none gets the same from the
request's method, path and body).
"""

from __future__ import annotations

import functools
import json
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from eth_utils import is_hex_address, to_checksum_address

from backend.chain.artifacts import PLATFORM_CONTRACTS, load_artifact
from backend.chain.pins import chain_pinned_for, read_pins, write_pin
from backend.chain.platform import Metric, TaskStatus, cid_commitment, domain_mask
from backend.settings import load_chain_client_settings
from backend.store import CID, InvalidCID
from workers.daemon.gateway import Gateway, GatewayError

UMC, TMC, MMC = PLATFORM_CONTRACTS
#: ``DRLAAS_CONTRACTS`` as a comma list names the contracts in this order.
_ORDER = (UMC, TMC, MMC)
_SHORT = {"umc": UMC, "tmc": TMC, "mmc": MMC}
PIN_SUFFIX = ".platform.json"
_TX_FIELDS = frozenset(
    {
        "from",
        "to",
        "value",
        "nonce",
        "chainId",
        "gas",
        "gasPrice",
        "maxFeePerGas",
        "maxPriorityFeePerGas",
        "type",
        "data",
        "accessList",
    }
)
_INT_FIELDS = ("value", "nonce", "chainId", "gas", "gasPrice", "maxFeePerGas",
               "maxPriorityFeePerGas", "type")
_HEX = re.compile(r"0x[0-9a-fA-F]*")


class TxRefused(GatewayError):
    """The transaction a gateway asked us to sign is not what the command means: nothing was
    signed. A :class:`GatewayError` (rule ``tx_refused``), so every command reports it."""

    def __init__(self, method: str, path: str, msg: str) -> None:
        super().__init__(method, path, 409, {"rule": "tx_refused", "msg": msg})
        # this client refused, not the gateway: no HTTP status in what the user reads
        self.args = (f"{method} {path}: tx_refused by this client: {msg}",)

    def __str__(self) -> str:
        return str(self.args[0])


class _Mismatch(ValueError):
    pass


# -- what a command means ------------------------------------------------------------------------
@dataclass(frozen=True)
class Arg:
    """A check of one argument that is not an exact value (``test`` says if it passes)."""

    what: str
    test: Callable[[Any], bool]


@dataclass(frozen=True)
class Call:
    """One contract call a command may sign: ``contract.function`` with these ``args`` (ABI
    argument name -> expected value or :class:`Arg`; a tuple's fields as ``p.domain``; the
    arguments not named are not the command's to decide) and this ``value`` (wei; ``None``:
    read with :attr:`value_from` from the chain). ``first_step``: the gateway sends it as a
    ``then: repeat`` step before the request's own transaction."""

    contract: str
    function: str
    args: Mapping[str, Any] = field(default_factory=dict)
    value: int | None = 0
    value_from: Callable[[Gateway, Pin], int] | None = None
    first_step: bool = False

    @property
    def name(self) -> str:
        return f"{self.contract}.{self.function}"


@dataclass(frozen=True)
class Expect:
    """The transactions a command agrees to sign for one request (``what`` names it)."""

    what: str
    calls: tuple[Call, ...]


def is_cid(value: Any) -> bool:
    try:
        CID.parse(value)
        return True
    except (InvalidCID, TypeError, ValueError):
        return False


ANY_CID = Arg("a CID", is_cid)


def _ids(path: str) -> list[int]:
    return [int(x) for x in re.findall(r"/(\d+)(?=/|$)", path)]


def expect_request(method: str, path: str, body: Any, sender: str) -> Expect:
    """What ``method path`` with ``body`` (signed in as ``sender``) may have the CLI sign: the
    transaction(s) the gateway's route sends for it (backend/api/routes). ``TxRefused``-worthy
    ``LookupError`` for a route the CLI does not know."""
    b: dict[str, Any] = body if isinstance(body, dict) else {}
    what = f"{method} {path}"
    ids = _ids(path)
    route = re.sub(r"/\d+(?=/|$)", "/{id}", path.split("?")[0].rstrip("/"))
    calls: tuple[Call, ...]
    if method != "POST":
        raise LookupError(f"{what}: no transaction is expected from it")
    if route == "/users/requesters":
        calls = (Call(UMC, "addRequester"),)
    elif route == "/users/workers":
        caps = {k: b[f] for k, f in (("cpuCores", "cpu_cores"), ("ramGb", "ram_gb"),
                                     ("gpuSeries", "gpu_series")) if f in b}
        add = dict(caps)
        if isinstance(b.get("domains"), list):
            add["domains"] = domain_mask(b["domains"])
        calls = (Call(UMC, "addWorker", add), Call(UMC, "updateCapabilities", caps))
    elif route == "/tasks":
        calls = (add_task_call(b),)
    elif route == "/tasks/{id}/allocate":
        calls = (Call(TMC, "allocateTask", {"taskId": ids[0]}),)
    elif route == "/tasks/{id}/reviews":
        calls = (
            Call(TMC, "reviewOutcome", {"taskId": ids[0], "worker": b.get("worker"),
                                        "review": b.get("review"),
                                        "accepted": b.get("accepted", True)}),
        )
    elif route == "/tasks/{id}/cancel":
        calls = (Call(TMC, "updateTaskStatus", {"taskId": ids[0],
                                                "status": int(TaskStatus.CANCELLED)}),)
    elif route == "/tasks/{id}/cancel-open-slots":
        calls = (Call(TMC, "cancelOpenSlots", {"taskId": ids[0]}),)
    elif route == "/models/commitments":
        calls = (Call(TMC, "commitCid", {"commitment": b.get("commitment")}),)
    elif route == "/models":
        cid = b.get("cid")
        calls = (
            Call(TMC, "commitCid", {"commitment": "0x" + cid_commitment(str(cid), sender).hex()},
                 first_step=True),
            Call(MMC, "addModel", {"cid": cid, "description": b.get("description", ""),
                                   "domain": b.get("domain", 0)}),
        )
    elif route == "/models/requests":
        calls = (allocate_model_call(b),)
    elif route == "/models/requests/{id}/reviews":
        calls = (
            Call(MMC, "updateModelRep", {"allocId": ids[0], "modelId": b.get("model_id"),
                                         "review": b.get("review")}),
        )
    else:
        raise LookupError(f"{what}: no transaction is known to be expected from it")
    return Expect(what, calls)


def share_model_expect(what: str, body: Mapping[str, Any], gw: Gateway) -> Expect:
    """``POST /models`` with ``body``: MMC.addModel of its CID, description and domain, after
    (``then: repeat``) the TMC.commitCid of that CID's commitment for us, if not made yet."""
    return Expect(what, expect_request("POST", "/models", body, gw.address).calls)


def add_task_call(body: Mapping[str, Any]) -> Call:
    """TMC.addTask of ``POST /tasks`` with ``body``: its terms, the escrow of ``payment_wei``
    per worker; the spec CID is the gateway's (it stores the spec), any CID."""
    workers = int(body.get("num_workers", 1))
    return Call(
        TMC,
        "addTask",
        {
            "p.domain": body.get("domain", 0),
            "p.numWorkers": workers,
            "p.minReputation": round(float(body.get("min_reputation", 0.0)) * 1_000_000),
            "p.minRating": round(float(body.get("min_rating", 0.0)) * 1_000_000),
            "p.minCpuCores": body.get("min_cpu_cores", 0),
            "p.minRamGb": body.get("min_ram_gb", 0),
            "p.duration": body.get("deadline_s"),
            "p.description": ANY_CID,
        },
        value=int(body.get("payment_wei", 0)) * workers,
    )


def allocate_model_call(body: Mapping[str, Any]) -> Call:
    """MMC.allocateModel of ``POST /models/requests``: paid ``price_wei`` x K, or the MMC's
    minimum price x K (read from the chain at the pinned MMC) when no price is given."""
    k = int(body.get("num_models", 1))
    metric = Metric.MODEL if body.get("metric") == "model" else Metric.SHARING
    args = {"r.domain": body.get("domain", 0), "r.numModels": k, "r.metric": int(metric)}
    price = body.get("price_wei")
    if price is not None:
        return Call(MMC, "allocateModel", args, value=int(price) * k)
    return Call(
        MMC,
        "allocateModel",
        args,
        value=None,
        value_from=lambda gw, pin: int(chain_call(gw, pin, MMC, "minModelPrice")) * k,
    )


# -- the pinned deployment -------------------------------------------------------------------------
@dataclass(frozen=True)
class Pin:
    """The deployment a gateway's transactions must target: chain id and contract addresses
    (checksummed), and where it came from (for messages)."""

    chain_id: int
    contracts: Mapping[str, str]
    source: str

    def contract_of(self, address: str) -> str | None:
        for name, a in self.contracts.items():
            if a.lower() == address.lower():
                return name
        return None


def pin_file(key: Path) -> Path:
    """Where the deployments seen with ``key`` are pinned: ``<key>.platform.json``."""
    return key.with_name(key.name + PIN_SUFFIX)


def _contracts(doc: Any, where: str) -> dict[str, str]:
    """{contract name: checksummed address} of a DRLAAS_CONTRACTS-like document or list."""
    if isinstance(doc, list):
        if len(doc) != 3:
            raise ValueError(f"{where}: give the {', '.join(_ORDER)} addresses, in this order")
        doc = dict(zip(_ORDER, doc, strict=True))
    if not isinstance(doc, dict):
        raise ValueError(f"{where}: not a JSON object or a list of addresses")
    if isinstance(doc.get("contracts"), dict):
        doc = doc["contracts"]
    out = {}
    for name in _ORDER:
        short = next(s for s, n in _SHORT.items() if n == name)
        v = doc.get(name, doc.get(short))
        if isinstance(v, dict):
            v = v.get("address")
        if not isinstance(v, str) or not is_hex_address(v):
            raise ValueError(f"{where}: no address for {name}")
        out[name] = to_checksum_address(v)
    return out


def _chain_id(value: Any, where: str) -> int:
    if isinstance(value, bool):
        raise ValueError(f"{where}: the chain id is not a number: {value!r}")
    try:
        out = int(value, 0) if isinstance(value, str) else int(value)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: the chain id is not a number: {value!r}") from None
    if out <= 0:
        raise ValueError(f"{where}: the chain id must be positive, got {out}")
    return out


def env_pin() -> tuple[int | None, dict[str, str] | None]:
    """``DRLAAS_CHAIN_ID`` and ``DRLAAS_CONTRACTS`` (a JSON document, the path of one, or the
    UMC,TMC,MMC addresses comma-separated), each None when unset."""
    chain = os.environ.get("DRLAAS_CHAIN_ID", "").strip()
    raw = os.environ.get("DRLAAS_CONTRACTS", "").strip()
    contracts = None
    if raw:
        if raw.startswith(("{", "[")):
            doc: Any = json.loads(raw)
        elif raw.startswith("0x"):
            doc = [a.strip() for a in raw.split(",")]
        else:
            doc = json.loads(Path(raw).read_text())
        contracts = _contracts(doc, "DRLAAS_CONTRACTS")
        if not chain and isinstance(doc, dict) and doc.get("chain_id") is not None:
            chain = str(doc["chain_id"])
    return (_chain_id(chain, "DRLAAS_CHAIN_ID") if chain else None), contracts


def platform_pin(gw: Gateway, key: Path | None) -> Pin:
    """The deployment ``gw``'s transactions must target: ``DRLAAS_CHAIN_ID`` /
    ``DRLAAS_CONTRACTS`` where set, else the one pinned for ``gw.url`` in ``<key>.platform.json``,
    else the gateway's ``GET /api/chain/contracts``, pinned now (trust on first use)."""
    chain_id, contracts = env_pin()
    if chain_id is not None and contracts is not None:
        return Pin(chain_id, contracts, "DRLAAS_CHAIN_ID / DRLAAS_CONTRACTS")
    path = pin_file(key) if key is not None else None
    pins = read_pins(path) if path is not None else {}
    entry = pins.get(gw.url)
    if entry is not None:
        where = f"{path} ({gw.url})"
        if not isinstance(entry, dict):
            raise ValueError(f"{where}: not a JSON object; remove the entry to pin again")
        pinned = Pin(_chain_id(entry.get("chain_id"), where),
                     _contracts(entry.get("contracts"), where),
                     f"pinned on first use in {path}")
    else:
        try:
            doc = gw.get("/chain/contracts")
        except GatewayError as exc:
            raise ValueError(
                f"cannot learn the platform's deployment (contracts, chain id) to check "
                f"against ({exc}); set DRLAAS_CONTRACTS and DRLAAS_CHAIN_ID"
            ) from None
        where = f"GET {gw.url}/api/chain/contracts"
        if not isinstance(doc, dict):
            raise ValueError(f"{where}: not a JSON object")
        pinned = Pin(_chain_id(doc.get("chain_id"), where), _contracts(doc, where),
                     "pinned on first use" + (f" in {path}" if path else ""))
        if path is not None:
            write_pin(path, gw.url, pinned.chain_id, pinned.contracts)
    return Pin(
        chain_id if chain_id is not None else pinned.chain_id,
        contracts if contracts is not None else pinned.contracts,
        pinned.source,
    )


def known_chain_id(gateway_url: str, key: Path | None) -> int | None:
    """The chain id already pinned for ``gateway_url`` (``DRLAAS_CHAIN_ID`` / the
    ``DRLAAS_CONTRACTS`` deployment, else ``<key>.platform.json``), without asking the gateway;
    ``None`` before the first write pins one."""
    chain_id, _ = env_pin()
    if chain_id is not None or key is None:
        return chain_id
    return chain_pinned_for(pin_file(key), gateway_url)


def reset_hint(gw: Gateway, key: Path | None) -> str:
    if key is None:
        return ("set DRLAAS_CONTRACTS and DRLAAS_CHAIN_ID to the deployment you trust if the "
                f"platform at {gw.url} was really redeployed")
    return (
        f"if the platform at {gw.url} was really redeployed, run `drlaas pin forget --gateway "
        f"{gw.url} --key {key}` (or remove the {gw.url!r} entry of {pin_file(key)}) to pin it "
        "again, or set DRLAAS_CONTRACTS and DRLAAS_CHAIN_ID to the deployment you trust"
    )


# -- reading the chain ----------------------------------------------------------------------------
@functools.cache
def _abi(contract: str) -> tuple[dict[str, Any], ...]:
    return tuple(load_artifact(contract, check=False)["abi"])


def contract(name: str, address: str | None = None, w3: Any = None) -> Any:
    from web3 import Web3

    w3 = w3 or Web3()
    if address is None:
        return w3.eth.contract(abi=list(_abi(name)))
    return w3.eth.contract(address=to_checksum_address(address), abi=list(_abi(name)))


def chain_url(gw: Gateway) -> str:
    """The JSON-RPC endpoint the CLI reads the chain at: ``DRLAAS_CHAIN`` when it is a node
    URL, else the gateway's ``/rpc`` (the embedded chain)."""
    from backend.settings import load_settings
    from workers.daemon.links import chain_url as url_of

    return url_of(load_settings(), gw.url)


def web3_of(gw: Gateway, timeout: float = 30.0) -> Any:
    from web3 import Web3

    return Web3(Web3.HTTPProvider(chain_url(gw), request_kwargs={"timeout": timeout}))


def chain_call(gw: Gateway, pin: Pin, name: str, fn: str, *args: Any) -> Any:
    """``name.fn(*args)`` read (eth_call) at the pinned address of contract ``name``."""
    return contract(name, pin.contracts[name], web3_of(gw)).functions[fn](*args).call()


def pinned_contract(gw: Gateway, key: Path | None, name: str) -> Any:
    """Contract ``name`` at the deployment pinned for ``gw`` (:func:`platform_pin`), to read
    what the chain records instead of what the gateway says: read at :func:`chain_url` once
    its chain id is checked to be the pinned one (ValueError naming both if not)."""
    pin = platform_pin(gw, key)
    w3 = web3_of(gw)
    chain_id = int(w3.eth.chain_id)
    if chain_id != pin.chain_id:
        raise ValueError(
            f"the chain at {chain_url(gw)} is chain {chain_id}, not {pin.chain_id} ({pin.source})"
        )
    return contract(name, pin.contracts[name], w3)


# -- the check ------------------------------------------------------------------------------------
def _int(tx: Mapping[str, Any], key: str) -> int | None:
    v = tx.get(key)
    if v is None:
        return None
    if isinstance(v, bool):
        raise _Mismatch(f"{key} is {v!r}, not a number")
    if isinstance(v, int):
        return v
    if isinstance(v, str) and _HEX.fullmatch(v) and len(v) > 2:
        return int(v, 16)
    raise _Mismatch(f"{key} is {v!r}, not a number")


def _same(expected: Any, got: Any) -> bool:
    if isinstance(expected, Arg):
        return expected.test(got)
    if isinstance(got, bytes):
        got = "0x" + got.hex()
    if isinstance(expected, bytes):
        expected = "0x" + expected.hex()
    if isinstance(expected, str) and isinstance(got, str):
        if expected.startswith("0x") and got.startswith("0x"):
            return expected.lower() == got.lower()
        return expected == got
    if isinstance(expected, bool) or isinstance(got, bool):
        return expected is got
    return bool(expected == got)


def _flat(args: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in args.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _show(v: Any) -> str:
    if isinstance(v, Arg):
        return v.what
    if isinstance(v, bytes):
        return "0x" + v.hex()
    return repr(v)


def decode_call(pin: Pin, to: str, data: str) -> tuple[str, str, dict[str, Any]]:
    """(contract, function, {argument: value}) of a call to ``to`` with ``data``; _Mismatch
    when ``to`` is none of the pinned contracts or ``data`` is not exactly one of its
    functions' encodings."""
    name = pin.contract_of(to)
    if name is None:
        raise _Mismatch(
            f"to is {to}, none of the platform's contracts ("
            + ", ".join(f"{n} {a}" for n, a in pin.contracts.items()) + f"; {pin.source})"
        )
    c = contract(name)
    try:
        fn, args = c.decode_function_input(data)
        reencoded = c.encode_abi(fn.fn_name, list(args.values()))
    except Exception as exc:  # noqa: BLE001 - web3/eth_abi raise several types on bad input
        raise _Mismatch(f"data is no call of a {name} function ({type(exc).__name__})") from None
    if reencoded.lower() != data.lower():
        raise _Mismatch(f"data is not the exact encoding of {name}.{fn.fn_name}")
    return name, str(fn.fn_name), _flat(args)


def check_tx(
    gw: Gateway,
    tx: Any,
    expect: Expect,
    *,
    first_step: bool,
    pin: Pin,
    key: Path | None = None,
    request: tuple[str, str] = ("POST", ""),
) -> dict[str, Any]:
    """``tx`` (a ``sign_locally`` body, answered to ``request``: method, path) if it is one
    of ``expect``'s calls on the pinned deployment, with bounded gas and fees; else
    :class:`TxRefused` naming the field and both values. Returns the fields to sign (ints as
    ints)."""
    method, path = request
    try:
        return _check(gw, tx, expect, first_step, pin, key)
    except _Mismatch as exc:
        raise TxRefused(
            method, path,
            f"refusing to sign the transaction the gateway {gw.url} asked for: {exc} "
            f"(`{expect.what}` expects {' or '.join(c.name for c in expect.calls)}); "
            "nothing was signed",
        ) from None


def _check(
    gw: Gateway, tx: Any, expect: Expect, first_step: bool, pin: Pin, key: Path | None
) -> dict[str, Any]:
    if not isinstance(tx, dict):
        raise _Mismatch(f"the transaction is {type(tx).__name__}, not an object")
    extra = sorted(set(tx) - _TX_FIELDS)
    if extra:
        raise _Mismatch(f"unexpected field(s) {', '.join(extra)}")
    fields: dict[str, Any] = {k: v for k, v in tx.items() if k not in _INT_FIELDS}
    for k in _INT_FIELDS:
        n = _int(tx, k)
        if n is not None:
            if n < 0:
                raise _Mismatch(f"{k} is negative ({n})")
            fields[k] = n
    tx_type = fields.get("type", 2 if "maxFeePerGas" in fields else 0)
    if tx_type not in (0, 2):
        raise _Mismatch(f"type is {tx_type}, expected 0 (legacy) or 2 (EIP-1559)")
    if fields.get("accessList") not in (None, []):
        raise _Mismatch("accessList is not empty")
    sender = gw.address
    if "from" in fields and (not isinstance(fields["from"], str)
                             or fields["from"].lower() != sender.lower()):
        raise _Mismatch(f"from is {fields['from']!r}, expected {sender}")
    chain_id = fields.get("chainId")
    if chain_id != pin.chain_id:
        raise _Mismatch(
            f"chainId is {chain_id}, expected {pin.chain_id} ({pin.source}); {reset_hint(gw, key)}"
        )
    to, data = fields.get("to"), fields.get("data", "0x")
    if not isinstance(to, str) or not is_hex_address(to):
        raise _Mismatch(f"to is {to!r}, not a contract address")
    if not isinstance(data, str) or not _HEX.fullmatch(data):
        raise _Mismatch(f"data is {data!r}, not 0x-hex")
    try:
        name, fn, args = decode_call(pin, to, data)
    except _Mismatch as exc:
        if pin.contract_of(to) is None:
            raise _Mismatch(f"{exc}; {reset_hint(gw, key)}") from None
        raise
    candidates = [c for c in expect.calls if c.contract == name and c.function == fn]
    if not candidates:
        raise _Mismatch(f"data calls {name}.{fn}")
    call = candidates[0]
    if call.first_step != first_step:
        raise _Mismatch(
            f"{name}.{fn} came as {'a first step' if first_step else 'the final step'}, "
            f"expected it as {'a first step' if call.first_step else 'the final step'}"
        )
    for arg, want in call.args.items():
        if want is None:
            continue
        got = args.get(arg)
        if arg not in args or not _same(want, got):
            raise _Mismatch(
                f"argument {arg} of {name}.{fn} is {_show(got)}, expected {_show(want)}"
            )
    value = call.value
    if value is None and call.value_from is not None:
        value = call.value_from(gw, pin)
    if fields.get("value", 0) != value:
        raise _Mismatch(f"value is {fields.get('value', 0)} wei, expected {value} wei")
    caps = load_chain_client_settings()  # the chain client's caps: one pair of settings
    if "gas" not in fields or fields["gas"] > caps.tx_max_gas:
        raise _Mismatch(
            f"gas is {fields.get('gas')}, expected at most {caps.tx_max_gas} (DRLAAS_TX_MAX_GAS)"
        )
    for k in ("gasPrice", "maxFeePerGas", "maxPriorityFeePerGas"):
        if fields.get(k, 0) > caps.tx_max_fee_per_gas_wei:
            raise _Mismatch(
                f"{k} is {fields[k]} wei, expected at most {caps.tx_max_fee_per_gas_wei} wei "
                "(DRLAAS_TX_MAX_FEE_PER_GAS_WEI)"
            )
    if tx_type == 2 and "gasPrice" in fields:
        raise _Mismatch("gasPrice is set on an EIP-1559 transaction")
    if tx_type == 0 and ("maxFeePerGas" in fields or "maxPriorityFeePerGas" in fields):
        raise _Mismatch("maxFeePerGas is set on a legacy transaction")
    return fields
