"""A small REST client of the gateway with EIP-4361 sign-in (backend.auth's flow).

Used by the worker daemon (progress points) and the CLI. The token is fetched on first use
and fetched again once when the gateway answers 401 (tokens are short-lived). Every answer is
read within bounds (:mod:`backend.httpbounds`): at most ``max_bytes`` (8 MiB; a request may
pass its own ``max_bytes``), within ``2 x timeout`` of its headers, 64 KiB of an error.
"""

from __future__ import annotations

import ipaddress
import json
import os
from typing import Any
from urllib.parse import urlsplit

import httpx
from eth_account.messages import encode_defunct
from eth_account.signers.local import LocalAccount

from backend.httpbounds import DEFAULT_MAX_BYTES, MAX_BYTES, bounded_client

API = "/api"


class GatewayError(RuntimeError):
    """A non-2xx answer, or one that is not what the API answers (not JSON, a field missing);
    ``status`` and the gateway's ``detail`` (rule + msg, or field list, or what was wrong)."""

    def __init__(self, method: str, path: str, status: int, detail: Any) -> None:
        self.status = status
        self.detail = detail
        super().__init__(f"{method} {path} -> {status}: {_show(detail)}")


def _show(detail: Any) -> str:
    if isinstance(detail, dict) and "msg" in detail:
        return f"{detail.get('rule', '')}: {detail['msg']}".lstrip(": ")
    if isinstance(detail, list):
        return "; ".join(
            f"{'.'.join(str(x) for x in d.get('loc', []))}: {d.get('msg')}"
            if isinstance(d, dict)
            else str(d)
            for d in detail
        )
    return str(detail)


class Gateway:
    """``Gateway(url, account)``: ``get``/``post`` JSON under ``/api``, signed in as
    ``account`` when ``auth=True``. Its own client bounds every answer (module docstring); a
    ``client`` given is used as it is."""

    def __init__(
        self,
        url: str,
        account: LocalAccount | None = None,
        *,
        timeout: float = 30.0,
        client: httpx.Client | None = None,
        max_bytes: int = DEFAULT_MAX_BYTES,
        chain_id: int | None = None,
    ) -> None:
        self.url = url.rstrip("/")
        self.account = account
        self.chain_id = chain_id
        """The chain a sign-in message must name (``None``: not checked)."""
        self._client = client or bounded_client(
            base_url=self.url, timeout=timeout, max_bytes=max_bytes
        )
        self._token: str | None = None

    def close(self) -> None:
        self._client.close()

    def __enter__(self) -> Gateway:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def address(self) -> str:
        if self.account is None:
            raise RuntimeError("this command needs a key file (--key) to sign in")
        return str(self.account.address)

    def sign_in(self) -> str:
        """nonce -> personal_sign -> bearer token (valid for the gateway's token TTL)."""
        r = self._client.post(f"{API}/auth/nonce", json={"address": self.address})
        self._check("POST", "/auth/nonce", r)
        message = _field("POST", "/auth/nonce", r, "message")
        refused = _sign_in_refusal(self.url, self.address, message, self.chain_id)
        if refused:  # a message for another site (relayed by a phishing gateway): never sign
            raise GatewayError("POST", "/auth/nonce", r.status_code, f"not signed: {refused}")
        assert self.account is not None
        sig = self.account.sign_message(encode_defunct(text=message)).signature
        r = self._client.post(
            f"{API}/auth/token", json={"message": message, "signature": "0x" + bytes(sig).hex()}
        )
        self._check("POST", "/auth/token", r)
        self._token = _field("POST", "/auth/token", r, "access_token")
        return self._token

    def request(
        self,
        method: str,
        path: str,
        *,
        auth: bool = False,
        max_bytes: int | None = None,
        **kwargs: Any,
    ) -> Any:
        """JSON body of ``method /api<path>``; :class:`GatewayError` on a non-2xx answer.
        ``max_bytes``: this answer's cap when it may be larger than the client's."""
        if max_bytes is not None:
            kwargs["extensions"] = {**(kwargs.get("extensions") or {}), MAX_BYTES: max_bytes}
        for attempt in (0, 1):
            headers = dict(kwargs.pop("headers", {}) or {})
            if auth:
                if self._token is None:
                    self.sign_in()
                headers["Authorization"] = f"Bearer {self._token}"
            r = self._client.request(method, f"{API}{path}", headers=headers, **kwargs)
            if r.status_code == 401 and auth and attempt == 0:
                self._token = None  # expired: sign in again once
                continue
            self._check(method, path, r)
            if r.status_code == 204 or not r.content:
                return None
            ctype = r.headers.get("content-type", "")
            return _json(method, path, r) if "json" in ctype else r.content
        raise AssertionError("unreachable")

    def rpc(self, path: str, method: str, params: list[Any]) -> Any:
        """``result`` of a JSON-RPC call to the chain the gateway serves at ``path``
        (``/rpc``); :class:`GatewayError` for an HTTP or JSON-RPC error."""
        r = self._client.post(
            path, json={"jsonrpc": "2.0", "id": 1, "method": method, "params": params}
        )
        self._check("POST", path, r)
        doc = _json("POST", path, r)
        if not isinstance(doc, dict):
            raise GatewayError("POST", f"{path} {method}", r.status_code, "not a JSON-RPC reply")
        if "error" in doc:
            raise GatewayError("POST", f"{path} {method}", r.status_code, doc["error"])
        return doc.get("result")

    def get(self, path: str, **kwargs: Any) -> Any:
        return self.request("GET", path, **kwargs)

    def post(self, path: str, json: Any = None, **kwargs: Any) -> Any:
        return self.request("POST", path, json=json, **kwargs)

    @staticmethod
    def _check(method: str, path: str, r: httpx.Response) -> None:
        if r.is_success:
            return
        try:
            doc = json.loads(r.content)
        except (ValueError, RecursionError):
            doc = None
        detail = doc.get("detail", r.text) if isinstance(doc, dict) else r.text[:500]
        raise GatewayError(method, path, r.status_code, detail)


_LOOPBACK_NAMES = frozenset({"localhost", "::1"})


def _origin(url: str) -> tuple[str, str, int]:
    """(scheme, host, port) of ``url``, the port explicit, a loopback host as ``loopback``."""
    parts = urlsplit(url if "://" in url else "//" + url)
    scheme = (parts.scheme or "").lower()
    host = (parts.hostname or "").lower()
    try:
        port = parts.port or {"https": 443, "http": 80}.get(scheme, 0)
    except ValueError:
        port = -1
    try:
        loopback = host in _LOOPBACK_NAMES or ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    return scheme, "loopback" if loopback else host, port


def _sign_in_refusal(
    gateway_url: str, address: str, message: str, chain_id: int | None = None
) -> str | None:
    """Why the EIP-4361 ``message`` a gateway at ``gateway_url`` asked ``address`` to sign is
    not DRLaaS's sign-in to that gateway (its domain and URI must name it, the address must be
    ours, the statement the platform's, the chain ``chain_id`` when it is known), or None when
    it is. Loopback names (localhost, 127.0.0.1, ::1) count as one host, with the same port."""
    from backend.auth import SIWE_STATEMENT, SiweMessage
    from backend.errors import DomainError

    try:
        msg = SiweMessage.parse(message)
    except DomainError:
        return "the sign-in message is not an EIP-4361 message as DRLaaS issues it"
    scheme, host, port = _origin(gateway_url)
    # a gateway reached by another name than the one it signs in as (docker-compose: workers
    # at http://gateway:8000, users at localhost:8000) is named by the operator, in the same
    # variables the gateway reads
    known = os.environ.get("DRLAAS_AUTH_DOMAIN"), os.environ.get("DRLAAS_AUTH_URI")
    # the domain is host[:port] with no scheme: read it with the gateway's (its default port)
    if _origin(f"{scheme}://{msg.domain}") != (scheme, host, port) and msg.domain != known[0]:
        return (f"the message is for domain {msg.domain!r}, not this gateway {gateway_url} "
                "(if the gateway signs in under another name, set DRLAAS_AUTH_DOMAIN and "
                "DRLAAS_AUTH_URI to its values)")
    if _origin(msg.uri) != (scheme, host, port) and msg.uri != known[1]:
        return f"the message is for URI {msg.uri!r}, not this gateway {gateway_url}"
    if msg.address.lower() != address.lower():
        return f"the message names the address {msg.address}, not ours ({address})"
    if msg.statement != SIWE_STATEMENT:
        return f"the message's statement {msg.statement!r} is not DRLaaS's sign-in statement"
    if chain_id is not None and msg.chain_id != chain_id:
        return f"the message is for chain {msg.chain_id}, not this platform's chain {chain_id}"
    return None


def _json(method: str, path: str, r: httpx.Response) -> Any:
    """The JSON body of a 2xx answer; GatewayError when it is not JSON (a proxy's HTML page)."""
    try:
        return json.loads(r.content)
    except (ValueError, RecursionError):
        raise GatewayError(
            method, path, r.status_code, f"answer is not JSON: {r.text[:200]!r}"
        ) from None


def _field(method: str, path: str, r: httpx.Response, key: str) -> str:
    """The string field ``key`` of a JSON object answer; GatewayError when it has none."""
    doc = _json(method, path, r)
    value = doc.get(key) if isinstance(doc, dict) else None
    if not isinstance(value, str):
        raise GatewayError(method, path, r.status_code, f"answer has no {key!r} string")
    return value
