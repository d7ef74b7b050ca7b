"""Platform settings: one pydantic-settings class read from ``DRLAAS_*`` environment variables.

Each service is chosen by one URL-like value, so the same code runs embedded on one machine or
against real services (ARCHITECTURE.md, "Service adapters"):

================  =====================================  ===========================================
variable          embedded (default)                     real service
================  =====================================  ===========================================
DRLAAS_CHAIN      ``embedded`` (eth-tester, in process)  ``http(s)://host:port`` JSON-RPC node
DRLAAS_IPFS       ``embedded`` or ``embedded:<dir>``     ``http(s)://host:5001`` IPFS RPC API
DRLAAS_BROKER     ``embedded`` (kombu SQLAlchemy over    ``redis://...``, ``rediss://...``,
                  a SQLite file, no server)              ``amqp://...``, ``amqps://...``
DRLAAS_DATABASE   ``sqlite:///<data>/drlaas.sqlite``     ``postgresql+psycopg://user@host/db``
================  =====================================  ===========================================

Errors name the environment variable (``DRLAAS_CHAIN: ...``) so a bad deployment says which line
of its environment is wrong; :func:`load_settings` turns pydantic's error list into one
:class:`SettingsError` with one line per bad variable.
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal
from urllib.parse import urlsplit

from pydantic import Field, SecretStr, ValidationError, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

ENV_PREFIX = "DRLAAS_"

#: Chain id of eth-tester's py-evm backend (the embedded chain); real nodes report their own.
EMBEDDED_CHAIN_ID = 131277322940537

#: Token secrets that are obviously not secret (lower-cased); rejected outside development.
PLACEHOLDER_SECRETS = frozenset(
    {
        "",
        "changethis",
        "changeme",
        "change-me",
        "secret",
        "password",
        "dev",
        "test",
        "token",
        "drlaas",
        "placeholder",
        "xxx",
        "todo",
    }
)
MIN_SECRET_LENGTH = 32
RPC_GAS_TOTAL_CLIENTS = 3
"""Default ``rpc_gas_per_minute_total``: as much as this many clients at their full rate."""


class SettingsError(ValueError):
    """Invalid platform settings; the message has one ``DRLAAS_<NAME>: reason`` line each."""


def env_name(field: str) -> str:
    """The environment variable that sets ``field``."""
    return f"{ENV_PREFIX}{field.upper()}"


@dataclass(frozen=True)
class ServiceURL:
    """A parsed service choice: ``kind`` is ``"embedded"`` or the real backend's name."""

    kind: str
    url: str

    @property
    def embedded(self) -> bool:
        return self.kind == "embedded"


class Settings(BaseSettings):
    """Everything the gateway, indexer and worker daemon need to know about their environment."""

    model_config = SettingsConfigDict(
        env_prefix=ENV_PREFIX, extra="ignore", validate_default=True, frozen=True
    )

    mode: Literal["development", "production"] = "development"
    """``production`` requires a real token secret and forbids demo keys held by the gateway."""
    data_dir: Path = Path(".drlaas")
    """Root of embedded state: broker/result SQLite files, embedded content store, database."""
    chain: str = "embedded"
    """``embedded`` or an http(s) JSON-RPC URL."""
    chain_id: int | None = Field(default=None, gt=0)
    """Chain id put into sign-in messages; default: eth-tester's id when embedded, else the
    id the node reports (the gateway sets it at start-up)."""
    ipfs: str = "embedded"
    """``embedded`` (= ``embedded:<data_dir>/ipfs``), ``embedded:<dir>`` or an IPFS RPC API URL."""
    broker: str = "embedded"
    """``embedded``, ``redis://``/``rediss://`` or ``amqp://``/``amqps://`` URL."""
    result_backend: str | None = None
    """Celery result backend; default: the Redis URL for Redis, else ``<data>/results.sqlite``,
    or (AMQP with PostgreSQL) a ``db+`` URL over DRLAAS_DATABASE."""
    database: str | None = None
    """SQLAlchemy URL, ``sqlite:///path`` or ``postgresql+psycopg://...``; default SQLite in
    the data dir."""
    migrate_on_start: bool = True
    """Run alembic ``upgrade head`` when the gateway starts."""

    token_secret: SecretStr | None = None
    """HMAC key of access tokens; required (>= 32 chars, not a placeholder) in production."""
    token_ttl_s: int = Field(default=900, ge=10, le=86_400)
    """Lifetime of an access token (short-lived: sign in again after it)."""
    metrics_token: SecretStr | None = None
    """Bearer token ``GET /metrics`` asks for (Prometheus: ``authorization.credentials``);
    unset, the scrape is anonymous, as in development (traffic, error and queue figures tell
    an attacker when the platform is loaded)."""
    auth_domain: str = "localhost:8000"
    """EIP-4361 ``domain`` (the gateway's host[:port]) that sign-in messages must name."""
    auth_uri: str = "http://localhost:8000"
    """EIP-4361 ``URI`` written into sign-in messages."""
    nonce_ttl_s: int = Field(default=300, ge=10, le=3600)
    """How long a sign-in message (its nonce) stays usable."""
    auth_nonces_per_minute: int = Field(default=30, ge=1, le=100_000)
    """Sign-in messages one remote client (``client_ipv6_prefix``) may ask for a minute; past it 429
    ``auth_rate_limited`` + Retry-After. Each is a database row until it expires, so this bounds
    what one client can make the gateway store (loopback clients are not metered)."""

    confirmations: int = Field(default=2, ge=0, le=1000)
    """Blocks to wait before trusting an event on a real chain (embedded: always 0)."""
    accept_window_s: int = Field(default=600, ge=1, le=2**32 - 1)
    """Default TMC acceptance window: an offer not accepted within it goes back to recruitment."""
    review_window_s: int = Field(default=86_400, ge=1, le=90 * 86_400)  # TMC.MAX_REVIEW_WINDOW
    """Default TMC review window: an outcome left unreviewed past it counts as accepted."""
    max_upload_bytes: int = Field(default=256 * 2**20, gt=0)
    """Largest model/content upload the gateway and store accept."""
    max_job_memory_gb: float = Field(default=8.0, gt=0, le=1e6)
    """Largest estimated peak memory of one training job a task may need
    (workers.mdrl.resources); beyond it task creation is a 422 ``spec_exceeds_memory_limit``."""
    max_task_worker_hours: float = Field(default=200.0, gt=0, le=1e7)
    """Largest estimated worker-hours (hours per worker x num_workers) of one task; beyond it
    task creation is a 422 ``spec_exceeds_worker_hours_limit``."""
    max_request_bytes: int = Field(default=2**20, ge=1024, le=2**30)
    """Largest request body the gateway reads (every route, before parsing: 413 above it)."""
    body_timeout_s: float = Field(default=10.0, gt=0, le=3600)
    """Seconds a client may take to send a request body; past it 408 ``body_timeout`` and the
    connection is closed (a body trickled byte by byte holds nothing for longer)."""
    max_json_depth: int = Field(default=64, ge=2, le=1000)
    """Deepest bracket nesting a request body may have (checked before parsing: 422)."""
    faucet_interval_s: int = Field(default=60, ge=0, le=86_400)
    """Embedded demo chain: seconds between two faucet top-ups of one address."""
    faucet_per_minute: int = Field(default=30, ge=1, le=10_000)
    """Embedded demo chain: faucet top-ups per minute over all addresses."""
    faucet_per_client_per_minute: int = Field(default=5, ge=1, le=10_000)
    """Embedded demo chain: faucet top-ups per minute for one client (IPv4 address or
    IPv6 network), whatever keys it signs in with, so one client cannot take the whole
    ``faucet_per_minute``."""
    faucet_max_per_address: int = Field(default=3, ge=1, le=10_000)
    """Embedded demo chain: top-ups one address may ever get (while the gateway runs); an
    address that sends its gas money away does not qualify again and again."""
    rpc_gas_cap: int = Field(default=8_000_000, ge=100_000, le=2**40)
    """Embedded ``/rpc``: most gas one ``eth_call`` / ``eth_estimateGas`` execution may use
    (geth's ``RPCGasCap``; a larger ``gas`` is clamped to it). Also the largest gas limit a
    transaction relayed by ``POST /api/tx`` may carry (on any chain; refused above it)."""
    rpc_gas_per_minute: int = Field(default=40_000_000, ge=100_000, le=2**50)
    """Embedded ``/rpc``: execution gas one client (IPv4 address or IPv6 network) may use a
    minute; past it JSON-RPC -32005 with the seconds to wait (backend.services.rpc_budget).
    At py-evm's ~3M gas a second this bounds one client's hold on the chain to ~13 s a
    minute."""
    rpc_gas_per_minute_total: int | None = Field(default=None, ge=100_000, le=2**52)
    """Embedded ``/rpc``: execution gas all remote clients together may use a minute, drawn
    with each client's own (default: 3 x ``rpc_gas_per_minute``, ~40 s of the chain lock a
    minute, so many clients or many networks together still leave time for platform writes);
    past it JSON-RPC -32005 "gateway-wide" with the seconds to wait. At least
    ``rpc_gas_per_minute``."""
    client_ipv6_prefix: int = Field(default=64, ge=32, le=128)
    """Prefix length of the IPv6 network that counts as one client for every per-client
    limit (``backend.api.client_key``): a host gets a /64 (often a /56 or /48), so keying by
    address would let one host be 2^64 clients. IPv4 addresses are one client each."""
    log_format: Literal["text", "json"] = "text"
    """``json``: one JSON object per log line (time, level, logger, message, task_id) for log
    collectors; ``text``: readable lines."""
    min_reward_per_hour_wei: int = Field(default=10**12, ge=0, lt=2**96)
    """Anti-spam minimum the embedded deployment sets on the TMC (wei per worker-hour; a task
    must pay at least this per hour of its deadline window per worker; 0 = none)."""
    min_model_price_wei: int = Field(default=10**12, ge=1, lt=2**80)
    """Least price per allocated model the embedded deployment sets on the MMC (wei): every
    allocation counts in the model's reputation (Eq. 10-11), so none may be free."""

    # -- overload (docs/platform.md, "Overload") --------------------------------------------
    max_in_flight: int = Field(default=64, ge=1, le=10_000)
    """Requests the gateway works on at once; beyond that it answers 503 + Retry-After."""
    retry_after_s: int = Field(default=1, ge=1, le=3600)
    """Retry-After (seconds) sent with every load-shedding 503."""
    max_downloads: int = Field(default=64, ge=1, le=10_000)
    """Streamed downloads (``/models/.../download``) at once over all clients; beyond that
    503 ``downloads_busy`` + Retry-After. A download holds no ``max_in_flight`` slot once its
    response starts."""
    max_downloads_per_client: int = Field(default=4, ge=1, le=1000)
    """Streamed downloads at once for one client (IPv4 address or IPv6 network); beyond that 429
    ``downloads_per_client`` + Retry-After."""
    max_store_reads: int = Field(default=24, ge=1, le=10_000)
    """Requests reading the content store at once over all clients; beyond that 503
    ``store_reads_busy`` + Retry-After. Keep it below the 40 threads sync routes share: a read
    of absent content waits for the node's find timeout in one of them."""
    rpc_requests_per_client: int = Field(default=2, ge=1, le=1000)
    """Embedded ``/rpc``: HTTP requests one remote client may have running at once (each may
    hold the chain lock, a batch up to 50 times); beyond that 429 ``rpc_busy_per_client`` +
    Retry-After. This machine's own workers and CLI are not bounded."""
    max_store_reads_per_client: int = Field(default=8, ge=1, le=1000)
    """Requests reading the content store at once for one client (IPv4 address or IPv6
    network); beyond that 429 ``store_reads_per_client`` + Retry-After."""
    download_idle_timeout_s: float = Field(default=30.0, gt=0, le=3600)
    """Seconds a download may wait on a client that reads nothing; then it is given up and
    its connection closed."""
    db_pool_size: int = Field(default=8, ge=1, le=1000)
    """Database connections kept open (SQLite and PostgreSQL)."""
    db_max_overflow: int = Field(default=8, ge=0, le=1000)
    """Extra connections opened under load beyond ``db_pool_size``."""
    db_pool_timeout_s: float = Field(default=5.0, gt=0, le=300)
    """Wait for a free connection before answering 503 + Retry-After."""

    # -- field checks (messages name the variable) ------------------------------------------
    @field_validator("data_dir")
    @classmethod
    def _check_data_dir(cls, v: Path) -> Path:
        # Absolute, so that SQLite URLs mean the same file in every process (workers, gateway).
        v = v.expanduser().resolve()
        if v.exists() and not v.is_dir():
            raise ValueError(f"{env_name('data_dir')} must be a directory, got the file {v}")
        return v

    @field_validator("metrics_token")
    @classmethod
    def _check_metrics_token(cls, v: SecretStr | None) -> SecretStr | None:
        # a token a scraper can guess protects nothing; unset (anonymous) must be explicit
        if v is not None and len(v.get_secret_value()) < 16:
            raise ValueError(f"{env_name('metrics_token')} must be at least 16 characters")
        return v

    @field_validator("chain")
    @classmethod
    def _check_chain(cls, v: str) -> str:
        v = v.strip()
        if v == "embedded" or _is_http(v):
            return v
        raise ValueError(
            f"{env_name('chain')} must be 'embedded' or an http(s) JSON-RPC URL, got {v!r}"
        )

    @field_validator("ipfs")
    @classmethod
    def _check_ipfs(cls, v: str) -> str:
        v = v.strip()
        if v == "embedded" or _is_http(v):
            return v
        if v.startswith("embedded:") and v[len("embedded:") :].strip():
            return v
        raise ValueError(
            f"{env_name('ipfs')} must be 'embedded', 'embedded:<dir>' or an http(s) URL of an "
            f"IPFS RPC API, got {v!r}"
        )

    @field_validator("broker")
    @classmethod
    def _check_broker(cls, v: str) -> str:
        v = v.strip()
        if v == "embedded":
            return v
        scheme = urlsplit(v).scheme
        if scheme in {"redis", "rediss", "amqp", "amqps"} and urlsplit(v).hostname:
            return v
        raise ValueError(
            f"{env_name('broker')} must be 'embedded', a redis:// or an amqp:// URL, got {v!r}"
        )

    @field_validator("database")
    @classmethod
    def _check_database(cls, v: str | None) -> str | None:
        if v is None:
            return None
        v = v.strip()
        scheme = urlsplit(v).scheme
        if scheme == "sqlite" and v.startswith("sqlite:///"):
            return v
        if scheme in {"postgresql+psycopg", "postgresql"}:
            # plain postgresql:// would pick psycopg2, which is not a dependency: use psycopg 3.
            return "postgresql+psycopg" + v[len(scheme) :]
        raise ValueError(
            f"{env_name('database')} must be 'sqlite:///<path>' or 'postgresql+psycopg://...', "
            f"got {v!r}"
        )

    @field_validator("auth_domain")
    @classmethod
    def _check_domain(cls, v: str) -> str:
        v = v.strip()
        if not v or any(c in v for c in "/ \n\t"):
            raise ValueError(
                f"{env_name('auth_domain')} must be a bare host[:port] (EIP-4361 domain), got {v!r}"
            )
        return v

    @model_validator(mode="after")
    def _check_rpc_gas_total(self) -> Settings:
        per_client, total = self.rpc_gas_per_minute, self.rpc_gas_per_minute_total
        if total is None:
            object.__setattr__(self, "rpc_gas_per_minute_total", RPC_GAS_TOTAL_CLIENTS * per_client)
        elif total < per_client:
            raise ValueError(
                f"{env_name('rpc_gas_per_minute_total')} ({total}) must be at least "
                f"{env_name('rpc_gas_per_minute')} ({per_client}): all clients together cannot "
                "have less gas a minute than one of them"
            )
        return self

    @model_validator(mode="after")
    def _check_secret(self) -> Settings:
        secret = self.token_secret.get_secret_value() if self.token_secret else None
        if self.mode == "development":
            if secret is None:
                # A fresh random key per process: tokens do not survive a gateway restart, which
                # is fine for development and never a guessable constant.
                object.__setattr__(self, "token_secret", SecretStr(secrets.token_urlsafe(32)))
            return self
        if secret is None:
            raise ValueError(f"{env_name('token_secret')} is required in production mode")
        if secret.strip().lower() in PLACEHOLDER_SECRETS:
            raise ValueError(
                f"{env_name('token_secret')} is a placeholder value; set a random secret "
                f"(e.g. python -c 'import secrets; print(secrets.token_urlsafe(32))')"
            )
        if len(secret) < MIN_SECRET_LENGTH:
            raise ValueError(
                f"{env_name('token_secret')} must be at least {MIN_SECRET_LENGTH} characters "
                f"in production mode, got {len(secret)}"
            )
        return self

    # -- derived values (computed here only) -------------------------------------------------
    @property
    def chain_service(self) -> ServiceURL:
        return ServiceURL("embedded" if self.chain == "embedded" else "rpc", self.chain)

    @property
    def ipfs_service(self) -> ServiceURL:
        """``embedded`` with ``url`` = the store directory, or ``rpc`` with the API URL."""
        if self.ipfs == "embedded":
            return ServiceURL("embedded", str(self.data_dir / "ipfs"))
        if self.ipfs.startswith("embedded:"):
            return ServiceURL("embedded", self.ipfs[len("embedded:") :])
        return ServiceURL("rpc", self.ipfs)

    @property
    def broker_service(self) -> ServiceURL:
        """Kind ``embedded``/``redis``/``amqp`` and the kombu broker URL."""
        if self.broker == "embedded":
            return ServiceURL("embedded", f"sqla+sqlite:///{self.data_dir / 'broker.sqlite'}")
        scheme = urlsplit(self.broker).scheme
        return ServiceURL("redis" if scheme.startswith("redis") else "amqp", self.broker)

    @property
    def database_url(self) -> str:
        return self.database or f"sqlite:///{self.data_dir / 'drlaas.sqlite'}"

    @property
    def effective_confirmations(self) -> int:
        """Blocks the indexer waits: none on the embedded chain (it never reorganises)."""
        return 0 if self.chain_service.embedded else self.confirmations

    @property
    def effective_chain_id(self) -> int | None:
        if self.chain_id is not None:
            return self.chain_id
        return EMBEDDED_CHAIN_ID if self.chain_service.embedded else None

    @property
    def secret_bytes(self) -> bytes:
        assert self.token_secret is not None  # set by _check_secret
        return self.token_secret.get_secret_value().encode()

    @property
    def demo_keys_allowed(self) -> bool:
        """The gateway may hold users' keys only in development (never in production)."""
        return self.mode == "development"


def _is_http(v: str) -> bool:
    parts = urlsplit(v)
    return parts.scheme in {"http", "https"} and bool(parts.hostname)


def load_settings(**overrides: Any) -> Settings:
    """Read settings from the environment (``overrides`` win), raising :class:`SettingsError`
    whose lines each start with the offending ``DRLAAS_*`` variable."""
    try:
        return Settings(**overrides)
    except ValidationError as exc:
        lines = []
        for err in exc.errors():
            field = str(err["loc"][0]) if err["loc"] else ""
            msg = err["msg"].removeprefix("Value error, ")
            name = env_name(field) if field else "settings"
            lines.append(msg if msg.startswith(ENV_PREFIX) else f"{name}: {msg}")
        raise SettingsError("invalid settings:\n  " + "\n  ".join(lines)) from None


class ChainClientSettings(BaseSettings):
    """What a JSON-RPC chain client (``Chain.rpc``: the gateway on a node, a worker, the CLI,
    the deploy job) accepts from its node before it signs (docs/platform.md, "Clients against
    hostile servers"). Read apart from :class:`Settings`, so a process that needs none of the
    gateway's settings (a worker, the deploy job) needs only these to be valid."""

    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, extra="ignore", frozen=True)

    chain_id: int | None = Field(default=None, gt=0)
    """The chain id the client signs for (the same ``DRLAAS_CHAIN_ID`` as :class:`Settings`);
    unset, the ``chain_id`` of the ``DRLAAS_CONTRACTS`` deployment when it names one. A node
    reporting another id is refused."""
    tx_max_fee_per_gas_wei: int = Field(default=100 * 10**9, ge=0, lt=2**256)
    """Largest ``gasPrice`` / ``maxFeePerGas`` (wei) the client signs; a node asking more is
    refused (the consortium chain runs at 0, anvil at 0, the embedded chain at ~1 gwei)."""
    tx_max_gas: int = Field(default=30_000_000, ge=21_000, le=2**63 - 1)
    """Largest gas limit the client signs (a node's estimate above it is refused)."""
    chain_max_response_bytes: int = Field(default=32 * 2**20, ge=2**16, le=2**34)
    """Largest JSON-RPC answer read from the node (``eth_getLogs`` is the largest)."""
    chain_timeout_s: float = Field(default=60.0, gt=0, le=3600)
    """Seconds a node may take per read; an answer's body must arrive within twice that."""


def load_chain_client_settings(**overrides: Any) -> ChainClientSettings:
    """:class:`ChainClientSettings` from the environment (``overrides`` win), raising
    :class:`SettingsError` whose lines each start with the offending ``DRLAAS_*`` variable."""
    try:
        return ChainClientSettings(**overrides)
    except ValidationError as exc:
        lines = []
        for err in exc.errors():
            field = str(err["loc"][0]) if err["loc"] else ""
            msg = err["msg"].removeprefix("Value error, ")
            lines.append(f"{env_name(field) if field else 'settings'}: {msg}")
        raise SettingsError("invalid chain client settings:\n  " + "\n  ".join(lines)) from None
