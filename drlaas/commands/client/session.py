"""What every REST client command shares: options, the signed-in session, writes that relay a
locally signed transaction, and output (a readable table or one JSON document).

Writes the gateway cannot sign itself come back as 409 ``sign_locally`` with the unsigned
transaction: :func:`write` signs it with the key file and relays it through ``POST /api/tx``
(docs/platform.md, "Signing").
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Annotated, Any

import typer
from web3 import Web3

from drlaas.commands.client.txcheck import (
    Expect,
    Pin,
    TxRefused,
    check_tx,
    expect_request,
    is_cid,
    known_chain_id,
    platform_pin,
)
from workers.daemon.funding import NoGas, ensure_gas
from workers.daemon.gateway import Gateway, GatewayError
from workers.daemon.keys import load_key, load_or_create_key

DEFAULT_GATEWAY = "http://127.0.0.1:8000"

GatewayOpt = Annotated[str, typer.Option("--gateway", envvar="DRLAAS_GATEWAY", help="gateway URL")]
KeyOpt = Annotated[
    Path, typer.Option("--key", envvar="DRLAAS_KEY", help="your key file (created if missing)")
]
"""The key of a command that can be a key's first use (register, submit, push, share, request):
a new key file is made at a path that holds none (pass ``create=True`` to :func:`connect`)."""
OwnKeyOpt = Annotated[
    Path, typer.Option("--key", envvar="DRLAAS_KEY", help="your key file (it must exist)")
]
"""The key of a command that acts on what the key already has (its task, its allocation, its
outcome): a mistyped path is an error naming it, not a new key with nothing to act on."""
JsonOpt = Annotated[bool, typer.Option("--json", help="print one JSON document")]


class CliGateway(Gateway):
    """A :class:`Gateway` that knows its key file (where the deployment is pinned,
    ``<key>.platform.json``: :mod:`drlaas.commands.client.txcheck`)."""

    def __init__(self, url: str, account: Any = None, key_path: Path | None = None) -> None:
        super().__init__(url, account)
        self.key_path = key_path
        self.pin: Pin | None = None

    def sign_in(self) -> str:
        """The gateway's sign-in, whose message must name the pinned chain once one is pinned
        (a gateway relaying another platform's sign-in is refused before anything is signed)."""
        if self.chain_id is None:
            try:
                self.chain_id = known_chain_id(self.url, self.key_path)
            except ValueError as exc:
                raise GatewayError("POST", "/auth/nonce", 0, f"not signed: {exc}") from None
        return super().sign_in()


def connect(gateway: str, key: Path | None = None, *, create: bool = False) -> Gateway:
    """A gateway session, signing in as the key file's account when ``key`` is given; a key
    file that does not exist is made only with ``create`` (else the command fails naming it)."""
    account = None
    if key is not None:
        try:
            account = load_or_create_key(key) if create else load_key(key)
        except (OSError, ValueError) as exc:
            fail(exc)
    return CliGateway(gateway or os.environ.get("DRLAAS_GATEWAY", DEFAULT_GATEWAY), account, key)


def connect_funded(gateway: str, key: Path, *, create: bool = False) -> Gateway:
    """:func:`connect`, then make sure the key can pay gas (the embedded demo chain's faucet
    tops up an empty key; elsewhere the error says who funds it)."""
    gw = connect(gateway, key, create=create)
    try:
        ensure_gas(gw)
    except (NoGas, GatewayError) as exc:
        gw.close()
        fail(exc)
    return gw


MAX_WRITE_STEPS = 3
"""Transactions one write may take: a first step (``then: repeat``, e.g. the CID commitment
before ``POST /models``) and the request's own, with room for one retry of the first."""


def write(
    gw: Gateway, method: str, path: str, body: Any = None, expect: Expect | None = None
) -> Any:
    """A write acting as the key's address: relay the transaction ourselves if the gateway
    answers ``sign_locally`` (it holds no key for us), and send the request again when that
    transaction was only a first step (``then: repeat``). Returns the endpoint's answer, or
    the relayed transaction's receipt (``{tx_hash, block_number, status, events}``).

    A transaction is signed only if it is what ``expect`` says (by default the one the
    gateway's route sends for this request, :func:`txcheck.expect_request`) on the pinned
    deployment: else :class:`~drlaas.commands.client.txcheck.TxRefused`, nothing signed."""
    for _ in range(MAX_WRITE_STEPS):
        try:
            return gw.request(method, path, json=body, auth=True)
        except GatewayError as exc:
            detail = exc.detail if isinstance(exc.detail, dict) else {}
            if exc.status != 409 or detail.get("rule") != "sign_locally" or "tx" not in detail:
                raise
            then = detail.get("then")
            fields = _checked(gw, method, path, body, expect, detail["tx"], then == "repeat")
            receipt = _relay(gw, sign(gw, fields))
            if then != "repeat":
                return receipt
    raise RuntimeError(f"{method} {path}: still asks for a first step after {MAX_WRITE_STEPS}")


def _checked(
    gw: Gateway,
    method: str,
    path: str,
    body: Any,
    expect: Expect | None,
    tx: Any,
    first_step: bool,
) -> dict[str, Any]:
    """``tx`` checked against ``expect`` and the pinned deployment (TxRefused otherwise)."""
    key = getattr(gw, "key_path", None)
    try:
        if expect is None:
            expect = expect_request(method, path, body, gw.address)
        pin = getattr(gw, "pin", None)
        if pin is None:
            pin = platform_pin(gw, key)
            if isinstance(gw, CliGateway):
                gw.pin = pin
    except (LookupError, ValueError) as exc:
        raise TxRefused(method, path, f"refusing to sign: {exc}; nothing was signed") from None
    return check_tx(
        gw, tx, expect, first_step=first_step, pin=pin, key=key, request=(method, path)
    )


def _relay(gw: Gateway, raw: str) -> Any:
    """POST the signed ``raw`` transaction to ``/api/tx`` (or the chain's JSON-RPC endpoint
    when the relay cannot decode it); its receipt."""
    try:
        return gw.post("/tx", {"raw": raw}, auth=True)
    except GatewayError as relay_exc:
        rule = relay_exc.detail.get("rule") if isinstance(relay_exc.detail, dict) else None
        if relay_exc.status != 422 or rule != "tx_invalid":
            raise
        # the relay could not decode a valid signed transaction: send it to the chain's
        # JSON-RPC endpoint ourselves (platform.md: clients may send raw transactions)
        return send_raw(gw.url + "/rpc", raw)


def sign(gw: Gateway, tx: dict[str, Any]) -> str:
    """The 0x-hex raw transaction of ``tx`` (as :func:`_checked` returns it: numbers decoded)
    signed by the key."""
    if gw.account is None:
        raise RuntimeError("this command needs a key file (--key) to sign")
    return "0x" + bytes(gw.account.sign_transaction(tx).raw_transaction).hex()


def send_raw(rpc_url: str, raw: str, timeout: float = 60.0) -> dict[str, Any]:
    """eth_sendRawTransaction at ``rpc_url`` and wait for the receipt; error if it reverted."""
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


def event_arg(receipt: dict[str, Any], event: str, arg: str) -> Any:
    """``args[arg]`` of the first ``event`` in a relayed receipt; LookupError naming both."""
    for e in receipt.get("events") or []:
        if e.get("name") == event:
            return e["args"][arg]
    raise LookupError(f"transaction {receipt.get('tx_hash')} emitted no {event} event")


_TERMINAL_UNSAFE = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u200e\u200f\u2028-\u202e"
                              "\u2066-\u2069]")
"""What a terminal acts on instead of showing: C0 and C1 controls (ESC starts sequences that
move the cursor, retitle the window, write the clipboard), and the bidi marks, embeddings,
overrides and isolates and the line separators (Unicode reorders or breaks what follows)."""


def terminal_text(text: str) -> str:
    """``text`` as the terminal should show it: every character in :data:`_TERMINAL_UNSAFE`
    written as its escape (``\\x1b``, ``\\u202e``); newlines and tabs kept. Text from a
    gateway is not trusted to be only text."""
    return _TERMINAL_UNSAFE.sub(lambda m: m.group().encode("unicode_escape").decode(), text)


def terminal_safe(doc: Any) -> Any:
    """``doc`` with :func:`terminal_text` applied to every string in it, keys included."""
    if isinstance(doc, str):
        return terminal_text(doc)
    if isinstance(doc, dict):
        return {terminal_safe(k): terminal_safe(v) for k, v in doc.items()}
    if isinstance(doc, list):
        return [terminal_safe(v) for v in doc]
    return doc


def fail(exc: Exception) -> None:
    typer.echo(f"error: {terminal_text(str(exc))}", err=True)
    raise typer.Exit(1)


def read(gateway: str, path: str, params: dict[str, Any] | None = None) -> Any:
    """GET ``path`` from the gateway (no sign-in needed); exit with the error on failure."""
    with connect(gateway) as gw:
        try:
            return gw.get(path, params=params) if params else gw.get(path)
        except GatewayError as exc:
            fail(exc)


def emit(doc: Any, as_json: bool, render: Any = None) -> None:
    """Print ``doc`` as JSON, or as ``render`` shows it: an answer of another shape than the
    one ``render`` reads (a hostile gateway's, another version's) is a one-line error."""
    if as_json or render is None:
        typer.echo(json.dumps(doc, indent=1, sort_keys=True, default=str))
        return
    try:
        render(terminal_safe(doc))
    except (KeyError, IndexError, TypeError, AttributeError, ValueError) as exc:
        fail(ValueError(f"the gateway's answer lacks what this command shows ({type(exc).__name__}"
                        f": {exc}); --json prints it as it is"))


MAX_CELL = 46
"""Longer cells of free text (a description) are cut to their ends in a table."""


def table(rows: list[dict[str, Any]], columns: list[tuple[str, str]]) -> str:
    """A plain fixed-width table of ``rows`` with (key, header) ``columns``. A cell holding a
    CID is printed in full, however long: users copy CIDs from tables into other commands. A
    row that is not an object (in a gateway's answer) is left out."""

    def cell(v: Any) -> str:
        if v is None:
            return "-"
        if isinstance(v, float):
            return f"{v:.3f}"
        s = terminal_text(str(v)).replace("\n", " ").replace("\t", " ")
        if len(s) <= MAX_CELL or any(is_cid(word) for word in s.split()):
            return s
        return s[:20] + "…" + s[-20:]

    objects = [r for r in rows if isinstance(r, dict)] if isinstance(rows, list) else []
    cells = [[cell(r.get(k)) for k, _ in columns] for r in objects]  # anything else: left out
    widths = [max([len(h)] + [len(c[i]) for c in cells]) for i, (_, h) in enumerate(columns)]
    lines = ["  ".join(h.ljust(w) for (_, h), w in zip(columns, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in cells]
    return "\n".join(lines)


def kv(doc: dict[str, Any], keys: list[str]) -> str:
    width = max(len(k) for k in keys)
    return "\n".join(f"{k.ljust(width)}  {terminal_text(str(doc.get(k, '-')))}" for k in keys)
