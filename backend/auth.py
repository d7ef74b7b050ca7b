"""Sign-in with an Ethereum key (EIP-4361 style) and short-lived bearer tokens.

Flow: ``issue_sign_in`` stores a random single-use nonce and returns the EIP-4361 message text;
the user signs it with ``personal_sign`` (EIP-191); ``verify_sign_in`` recovers the signer,
checks domain, chain id, nonce (known, issued to that address, unused, unexpired) and marks the
nonce used; ``issue_token`` returns an HS256 JWT (PyJWT) bound to the address. A request then
acts only as that address (``require_self``).

Every failure raises a :mod:`backend.errors` domain error with a named rule, e.g.
``siwe_nonce_used`` (a replay) or ``token_expired``.
"""

from __future__ import annotations

import datetime as dt
import re
import secrets
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol, cast

import jwt
from eth_account import Account
from eth_account.messages import encode_defunct
from eth_account.signers.local import LocalAccount
from sqlalchemy import CursorResult, delete, update
from sqlalchemy.orm import Session

from backend.chain.addresses import checksum
from backend.db.base import utcnow
from backend.db.models import AuthNonce
from backend.errors import Forbidden, Invalid, Unauthorized
from backend.settings import Settings

Clock = Callable[[], dt.datetime]

TOKEN_ALGORITHM = "HS256"
TOKEN_AUDIENCE = "drlaas-gateway"
SIWE_VERSION = "1"
SIWE_STATEMENT = "Sign in to DRLaaS. This request costs nothing and sends no transaction."


def _unauthorized(rule: str, msg: str) -> Unauthorized:
    return Unauthorized(rule, msg)


# -- EIP-4361 message ---------------------------------------------------------------------------
def _iso(t: dt.datetime) -> str:
    return t.astimezone(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _parse_iso(s: str, field: str) -> dt.datetime:
    """An ISO 8601 timestamp with a time zone, in UTC; ``ValueError`` naming ``field`` (the
    message's line) otherwise, also for one that UTC cannot hold (9999-12-31T23:59:59-14:00 is
    in year 10000: ``astimezone`` raises OverflowError, which answered 500)."""
    try:
        t = dt.datetime.fromisoformat(s.replace("Z", "+00:00"))
        if t.tzinfo is None:
            raise ValueError("no time zone")
        return t.astimezone(dt.UTC)
    except (ValueError, OverflowError) as exc:
        raise ValueError(f"{field}: {s[:64]!r} is not a UTC-representable timestamp with a "
                         f"time zone ({exc})") from None


@dataclass(frozen=True)
class SiweMessage:
    """The fields of an EIP-4361 message that the gateway issues and checks."""

    domain: str
    address: str
    statement: str
    uri: str
    chain_id: int
    nonce: str
    issued_at: dt.datetime
    expiration_time: dt.datetime
    version: str = SIWE_VERSION

    def text(self) -> str:
        """The exact text to sign (EIP-4361 layout)."""
        return (
            f"{self.domain} wants you to sign in with your Ethereum account:\n"
            f"{self.address}\n"
            f"\n"
            f"{self.statement}\n"
            f"\n"
            f"URI: {self.uri}\n"
            f"Version: {self.version}\n"
            f"Chain ID: {self.chain_id}\n"
            f"Nonce: {self.nonce}\n"
            f"Issued At: {_iso(self.issued_at)}\n"
            f"Expiration Time: {_iso(self.expiration_time)}"
        )

    @classmethod
    def parse(cls, text: str) -> SiweMessage:
        """Parse the subset of EIP-4361 the gateway issues; ``Invalid`` (422) when malformed."""
        m = _SIWE_RE.fullmatch(text.replace("\r\n", "\n"))
        if m is None:
            raise Invalid(
                "siwe_message_malformed",
                "message is not an EIP-4361 sign-in message as issued by POST /api/auth/nonce",
            )
        try:
            return cls(
                domain=m["domain"],
                address=checksum(m["address"]),
                statement=m["statement"],
                uri=m["uri"],
                version=m["version"],
                chain_id=int(m["chain_id"]),
                nonce=m["nonce"],
                issued_at=_parse_iso(m["issued_at"], "Issued At"),
                expiration_time=_parse_iso(m["expiration_time"], "Expiration Time"),
            )
        except ValueError as exc:
            raise Invalid("siwe_message_malformed", str(exc)) from None


_SIWE_RE = re.compile(
    r"(?P<domain>[^\s/]+) wants you to sign in with your Ethereum account:\n"
    r"(?P<address>0x[0-9a-fA-F]{40})\n"
    r"\n"
    r"(?P<statement>[^\n]*)\n"
    r"\n"
    r"URI: (?P<uri>\S+)\n"
    r"Version: (?P<version>\d+)\n"
    r"Chain ID: (?P<chain_id>\d+)\n"
    r"Nonce: (?P<nonce>[0-9A-Za-z]{8,64})\n"
    r"Issued At: (?P<issued_at>\S+)\n"
    r"Expiration Time: (?P<expiration_time>\S+)"
)


# -- nonce issue / verification -----------------------------------------------------------------
def issue_sign_in(
    session: Session, *, address: str, settings: Settings, chain_id: int, now: dt.datetime
) -> SiweMessage:
    """Store a fresh single-use nonce for ``address`` and return the message to sign.

    Expired nonces are purged here (indexed on ``expires_at``), so the table stays small."""
    address = checksum(address)
    now = now.replace(microsecond=0)
    msg = SiweMessage(
        domain=settings.auth_domain,
        address=address,
        statement=SIWE_STATEMENT,
        uri=settings.auth_uri,
        chain_id=chain_id,
        nonce=secrets.token_hex(16),
        issued_at=now,
        expiration_time=now + dt.timedelta(seconds=settings.nonce_ttl_s),
    )
    session.execute(delete(AuthNonce).where(AuthNonce.expires_at < now))
    session.add(
        AuthNonce(nonce=msg.nonce, address=address, issued_at=now, expires_at=msg.expiration_time)
    )
    session.commit()
    return msg


def recover_signer(text: str, signature: str) -> str:
    """Address that ``personal_sign``-ed ``text`` (EIP-191 version 0x45)."""
    try:
        return Account.recover_message(encode_defunct(text=text), signature=signature)
    except Exception:  # eth_account raises several types for malformed signatures
        raise _unauthorized(
            "siwe_signature_invalid", "signature is not a valid 65-byte secp256k1 signature"
        ) from None


def verify_sign_in(
    session: Session,
    *,
    message: str,
    signature: str,
    settings: Settings,
    chain_id: int,
    now: dt.datetime,
) -> str:
    """Check a signed sign-in message and consume its nonce; return the signer's address.

    Order matters: everything that needs no database write is checked first, and the nonce is
    consumed with a conditional UPDATE, so two concurrent requests with one nonce cannot both
    succeed."""
    msg = SiweMessage.parse(message)
    if msg.domain != settings.auth_domain:
        raise _unauthorized(
            "siwe_domain_mismatch",
            f"message is for domain {msg.domain!r}, this gateway is {settings.auth_domain!r}",
        )
    if msg.version != SIWE_VERSION:
        raise _unauthorized("siwe_version", f"unsupported EIP-4361 version {msg.version!r}")
    if msg.chain_id != chain_id:
        raise _unauthorized(
            "siwe_chain_mismatch",
            f"message is for chain {msg.chain_id}, this gateway is {chain_id}",
        )
    signer = recover_signer(message, signature)
    if signer != msg.address:
        raise _unauthorized(
            "siwe_signature_mismatch",
            f"message names {msg.address} but was signed by {signer}",
        )
    row = session.get(AuthNonce, msg.nonce)
    if row is None:
        raise _unauthorized("siwe_nonce_unknown", "nonce was not issued here or has expired")
    if row.address != msg.address:
        raise _unauthorized("siwe_nonce_address", "nonce was issued to another address")
    if row.used_at is not None:
        raise _unauthorized("siwe_nonce_used", "nonce was already used: request a new message")
    issued = SiweMessage(
        domain=settings.auth_domain,
        address=row.address,
        statement=SIWE_STATEMENT,
        uri=settings.auth_uri,
        chain_id=chain_id,
        nonce=row.nonce,
        issued_at=row.issued_at,
        expiration_time=row.expires_at,
    ).text()
    if message != issued:  # statement, URI, times, extra lines: the text issued, not a variant
        line = next(
            (
                f"line {i + 1}: {got!r}"
                for i, (got, want) in enumerate(
                    zip(message.split("\n"), issued.split("\n"), strict=False)
                )
                if got != want
            ),
            "its length",
        )
        raise _unauthorized(
            "siwe_message_altered",
            f"the signed message is not the one issued for this nonce (it differs at {line[:120]})",
        )
    if now >= min(row.expires_at, msg.expiration_time):
        raise _unauthorized("siwe_expired", "sign-in message has expired: request a new one")
    consumed = cast(
        CursorResult[Any],
        session.execute(
            update(AuthNonce)
            .where(AuthNonce.nonce == msg.nonce, AuthNonce.used_at.is_(None))
            .values(used_at=now)
        ),
    )
    session.commit()
    if consumed.rowcount != 1:  # lost a race with another request carrying the same nonce
        raise _unauthorized("siwe_nonce_used", "nonce was already used: request a new message")
    return msg.address


# -- tokens -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Token:
    access_token: str
    address: str
    expires_at: dt.datetime


def issue_token(address: str, *, settings: Settings, now: dt.datetime | None = None) -> Token:
    """An HS256 JWT bound to ``address`` (``sub``), valid ``settings.token_ttl_s`` seconds."""
    now = (now or utcnow()).replace(microsecond=0)
    exp = now + dt.timedelta(seconds=settings.token_ttl_s)
    subject = checksum(address)
    claims = {
        "sub": subject,
        "iss": settings.auth_domain,
        "aud": TOKEN_AUDIENCE,
        "iat": now,
        "exp": exp,
        "jti": uuid.uuid4().hex,
    }
    token = jwt.encode(claims, settings.secret_bytes, algorithm=TOKEN_ALGORITHM)
    return Token(access_token=token, address=subject, expires_at=exp)


def decode_token(token: str, *, settings: Settings) -> str:
    """The address a valid token is bound to; 401 ``token_expired`` / ``token_invalid``.

    The algorithm list is pinned, so ``alg: none`` or an asymmetric-key confusion is refused."""
    try:
        claims = jwt.decode(
            token,
            settings.secret_bytes,
            algorithms=[TOKEN_ALGORITHM],
            audience=TOKEN_AUDIENCE,
            issuer=settings.auth_domain,
            options={"require": ["sub", "exp", "iat", "aud", "iss"]},
        )
    except jwt.ExpiredSignatureError:
        raise _unauthorized("token_expired", "access token has expired: sign in again") from None
    except jwt.InvalidTokenError as exc:
        raise _unauthorized("token_invalid", f"access token rejected: {exc}") from None
    try:
        return checksum(claims["sub"])
    except ValueError:
        raise _unauthorized("token_invalid", "access token subject is not an address") from None


@dataclass(frozen=True)
class User:
    """The caller, as proven by a token: only ever an Ethereum address."""

    address: str


def require_self(user: User, address: str) -> str:
    """Allow acting as ``address`` only for the user who signed in with it (403 otherwise)."""
    try:
        target = checksum(address)
    except ValueError as exc:
        raise Invalid("address_invalid", str(exc)) from None
    if target != user.address:
        raise Forbidden(
            "act_as_self_only",
            f"signed in as {user.address}; a request can only act as the address that signed",
        )
    return target


# -- demo keys (development only) ----------------------------------------------------------------
class _Poster(Protocol):
    def post(self, url: str, *, json: Any) -> Any: ...


class DemoKeys:
    """Private keys of demo users held by the platform process, for the scripted scenario.

    Only in development mode: in production users sign locally and the gateway never sees a key.
    """

    def __init__(self, settings: Settings) -> None:
        if not settings.demo_keys_allowed:
            raise RuntimeError(
                "DemoKeys is refused in production mode (DRLAAS_MODE=production): users sign "
                "with their own keys"
            )
        self._accounts: dict[str, LocalAccount] = {}

    def add(self, name: str, key: str | bytes | LocalAccount) -> str:
        """Register ``name`` with a key (hex, bytes or account); returns its address."""
        account = key if isinstance(key, LocalAccount) else Account.from_key(key)
        if name in self._accounts and self._accounts[name].address != account.address:
            raise ValueError(f"demo user {name!r} already holds another key")
        self._accounts[name] = account
        return account.address

    def create(self, name: str) -> str:
        """A fresh random key for ``name``; returns its address."""
        return self.add(name, Account.create())

    @property
    def names(self) -> list[str]:
        return list(self._accounts)

    def account(self, name: str) -> LocalAccount:
        try:
            return self._accounts[name]
        except KeyError:
            raise KeyError(f"no demo user {name!r}; known: {sorted(self._accounts)}") from None

    def address(self, name: str) -> str:
        return self.account(name).address

    def sign(self, name: str, text: str) -> str:
        """``personal_sign`` of ``text`` by ``name``, as a 0x-hex signature."""
        signed = self.account(name).sign_message(encode_defunct(text=text))
        return "0x" + bytes(signed.signature).hex()

    def sign_in(self, client: _Poster, name: str, *, prefix: str = "/api") -> str:
        """Run the nonce -> signature -> token flow over ``client`` (httpx or TestClient) and
        return the bearer token."""
        r = client.post(f"{prefix}/auth/nonce", json={"address": self.address(name)})
        r.raise_for_status()
        message = r.json()["message"]
        r = client.post(
            f"{prefix}/auth/token", json={"message": message, "signature": self.sign(name, message)}
        )
        r.raise_for_status()
        return str(r.json()["access_token"])


def bearer_headers(token: str) -> Mapping[str, str]:
    return {"Authorization": f"Bearer {token}"}
