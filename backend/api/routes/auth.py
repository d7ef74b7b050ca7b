"""Sign-in with an Ethereum key: ``POST /auth/nonce`` then ``POST /auth/token`` (EIP-4361).

The gateway never sees a private key: the client signs the returned message locally
(``personal_sign``) and exchanges message + signature for a short-lived bearer token.
"""

from __future__ import annotations

import datetime as dt

from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

from backend.api.client_key import client_key
from backend.api.deps import (
    ChainDep,
    ChainIdDep,
    ClockDep,
    CurrentUser,
    SessionDep,
    SettingsDep,
    is_loopback,
)
from backend.api.errors import RuleError, rule_responses
from backend.api.schemas import Address
from backend.auth import issue_sign_in, issue_token, verify_sign_in
from backend.errors import RateLimited
from backend.schemas.common import WRITE_BODY
from backend.services.rpc_budget import GasBudget

router = APIRouter(prefix="/auth", tags=["auth"])


class NonceRequest(BaseModel):
    model_config = WRITE_BODY

    address: Address


class NoncePublic(BaseModel):
    message: str = Field(description="EIP-4361 text to sign with personal_sign, unchanged")
    nonce: str
    expires_at: dt.datetime


class TokenRequest(BaseModel):
    model_config = WRITE_BODY

    message: str = Field(min_length=1, max_length=4096)
    signature: str = Field(pattern=r"^(0x)?[0-9a-fA-F]{130}$", description="65-byte signature, hex")


class TokenPublic(BaseModel):
    access_token: str
    token_type: str = "bearer"
    address: str
    expires_at: dt.datetime


class UserPublic(BaseModel):
    address: str


@router.post("/nonce", response_model=NoncePublic, responses=rule_responses(429, 503))
def create_nonce(
    body: NonceRequest,
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    chain_id: ChainIdDep,
    now: ClockDep,
) -> NoncePublic:
    """A sign-in message with a fresh single-use nonce for ``address``; at most
    ``auth_nonces_per_minute`` per remote client (429 ``auth_rate_limited`` + Retry-After)."""
    if not is_loopback(request):
        budget: GasBudget = request.app.state.nonce_budget
        client = client_key(request)
        wait = budget.take(client, 1)
        if wait:
            raise RateLimited(
                "auth_rate_limited",
                f"at most {budget.per_minute} sign-in messages a minute per client",
                retry_after=wait,
            )
    msg = issue_sign_in(
        session, address=body.address, settings=settings, chain_id=chain_id, now=now
    )
    return NoncePublic(message=msg.text(), nonce=msg.nonce, expires_at=msg.expiration_time)


@router.post("/token", response_model=TokenPublic, responses=rule_responses(401, 422, 503))
def create_token(
    body: TokenRequest,
    session: SessionDep,
    settings: SettingsDep,
    chain_id: ChainIdDep,
    now: ClockDep,
) -> TokenPublic:
    """Exchange a signed sign-in message for a bearer token bound to the signer."""
    address = verify_sign_in(
        session,
        message=body.message,
        signature=body.signature,
        settings=settings,
        chain_id=chain_id,
        now=now,
    )
    token = issue_token(address, settings=settings)
    return TokenPublic(
        access_token=token.access_token, address=token.address, expires_at=token.expires_at
    )


@router.get("/me", response_model=UserPublic, responses=rule_responses(401))
def me(user: CurrentUser) -> UserPublic:
    """Who the bearer token says the caller is."""
    return UserPublic(address=user.address)


class DemoUserPublic(BaseModel):
    name: str
    address: str


class DemoUsersPublic(BaseModel):
    data: list[DemoUserPublic]
    count: int


class DemoTokenRequest(BaseModel):
    model_config = WRITE_BODY

    name: str = Field(min_length=1, max_length=64)
    address: Address


def _demo_keys(chain: ChainDep, request: Request):
    """The gateway's demo keys, for clients on this machine only: a token for a demo user
    (the consortium admin among them) lets the gateway sign as that user, so handing one to
    the network would hand anyone the admin's rights."""
    if chain.demo_keys is None:
        raise RuleError(404, "demo_disabled", "this gateway holds no demo keys (production mode)")
    if not is_loopback(request):
        raise RuleError(
            404, "demo_not_local", "demo users are served to this machine only (loopback)"
        )
    return chain.demo_keys


@router.get("/demo-users", response_model=DemoUsersPublic, responses=rule_responses(404, 503))
def demo_users(chain: ChainDep, request: Request) -> DemoUsersPublic:
    """Development only, loopback clients only: the demo users whose keys the gateway holds
    (for the web UI)."""
    keys = _demo_keys(chain, request)
    data = [DemoUserPublic(name=n, address=keys.account(n).address) for n in keys.names]
    return DemoUsersPublic(data=data, count=len(data))


@router.post("/demo-token", response_model=TokenPublic, responses=rule_responses(403, 404, 503))
def demo_token(
    body: DemoTokenRequest, chain: ChainDep, settings: SettingsDep, request: Request
) -> TokenPublic:
    """Development only, loopback clients only: a token for a demo user; the gateway holds that
    key, so it vouches."""
    keys = _demo_keys(chain, request)
    if body.name not in keys.names or keys.account(body.name).address != body.address:
        raise RuleError(
            403, "not_a_demo_user", f"{body.name}/{body.address} is not a demo user here"
        )
    token = issue_token(body.address, settings=settings)
    return TokenPublic(
        access_token=token.access_token, address=token.address, expires_at=token.expires_at
    )
