"""A consortium chain for Hyperledger Besu with QBFT: validator keys, genesis and peer list.

:func:`generate` writes everything a group of members needs to start the chain once:

* ``keys/validator-<i>.key`` - one secp256k1 node key per validator (Besu's key-file format,
  ``0x`` + 64 hex digits, mode 0600). In QBFT a node's address *is* its validator address.
* ``keys/deployer.key`` - the account that deploys the platform contracts (funded in genesis).
* ``worker-keys/worker-<i>.key`` - one key per worker container (``drlaas deploy worker``
  claims a free one at start, so ``--scale worker=N`` gives N distinct identities).
* ``public/genesis.json`` - QBFT genesis: validators in ``extraData``, Cancun from block 0,
  zero base fee (the consortium runs free gas), 30M gas limit, the deployer funded.
* ``public/static-nodes.json`` and ``public/validators.json`` - enode URLs derived from the
  public keys, so the validators find each other without discovery.

Keys are never overwritten: generating again over an existing directory would describe a
different chain, so it is refused.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rlp
from eth_account import Account
from eth_account.signers.local import LocalAccount
from eth_keys import keys as eth_keys

GAS_LIMIT = 30_000_000  # one block holds a 30M-gas allocation (issue 8, item 2)
DEPLOYER_BALANCE = 10**6 * 10**18  # 1,000,000 ETH: value transfers only, gas is free
BFT_MIX_HASH = "0x63746963616c2062797a616e74696e65206661756c7420746f6c6572616e6365"
"""The mixHash every IBFT 2.0 / QBFT block carries ("Istanbul practical byzantine fault
tolerance" digest); Besu rejects a BFT genesis without it."""
P2P_PORT = 30303

# Every block-numbered fork from genesis, then the timestamp forks. Cancun is what the
# contracts need (transient storage in withdraw, evmVersion "cancun" in solc-settings.json).
# Prague stays off: Besu refuses Prague without its system contracts pre-deployed and does
# not yet support Prague for QBFT (besu-eth/besu#9409).
_BLOCK_FORKS = (
    "homesteadBlock",
    "eip150Block",
    "eip155Block",
    "eip158Block",
    "byzantiumBlock",
    "constantinopleBlock",
    "petersburgBlock",
    "istanbulBlock",
    "berlinBlock",
    "londonBlock",
)
_TIME_FORKS = ("shanghaiTime", "cancunTime")


@dataclass(frozen=True)
class Node:
    """A validator: its name (compose service / host), key file and derived identities."""

    name: str
    key_file: Path
    address: str
    public_key: bytes  # 64 bytes, uncompressed without the 0x04 prefix

    def enode(self, host: str | None = None, port: int = P2P_PORT) -> str:
        return f"enode://{self.public_key.hex()}@{host or self.name}:{port}"


def node_of(name: str, key_file: Path) -> Node:
    """The identities of the validator whose key is in ``key_file``."""
    public = eth_keys.PrivateKey(bytes(read_key(key_file).key)).public_key
    return Node(name, key_file, public.to_checksum_address(), public.to_bytes())


def read_key(path: str | os.PathLike[str]) -> LocalAccount:
    """The account in a key file (``0x`` + hex, as :func:`write_key` writes)."""
    p = Path(path)
    try:
        return Account.from_key(p.read_text().strip())
    except OSError as exc:
        raise FileNotFoundError(f"cannot read key file {p}: {exc}") from None
    except Exception:  # noqa: BLE001 - eth_account raises several types
        raise ValueError(f"key file {p}: not a 32-byte hex private key") from None


def write_key(path: Path, account: LocalAccount | None = None) -> LocalAccount:
    """Write a new key to ``path`` readable by its owner only (0600); never overwrites."""
    account = account or Account.create()
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write("0x" + bytes(account.key).hex() + "\n")
    return account


def qbft_extra_data(validators: Sequence[str]) -> str:
    """QBFT genesis extraData: RLP([32-byte vanity, [validators], no vote, round 0, no seals]).

    Besu's QbftExtraDataCodec writes the absent vote as an empty list and round 0 as the
    empty scalar; the genesis block has no committed seals."""
    if not validators:
        raise ValueError("a QBFT chain needs at least one validator")
    addresses = [bytes.fromhex(a.removeprefix("0x")) for a in validators]
    if any(len(a) != 20 for a in addresses):
        raise ValueError(f"validator addresses must be 20 bytes: {list(validators)}")
    return "0x" + rlp.encode([b"\x00" * 32, addresses, [], b"", []]).hex()


def qbft_genesis(
    validators: Sequence[str],
    deployer: str,
    *,
    chain_id: int,
    block_period: int = 2,
    epoch_length: int = 30_000,
    request_timeout: int = 4,
    deployer_balance: int = DEPLOYER_BALANCE,
    timestamp: int | None = None,
) -> dict[str, Any]:
    """A Besu QBFT genesis (see the module docstring for what it enables)."""
    if chain_id <= 0:
        raise ValueError(f"chain id must be positive, got {chain_id}")
    if not 0 < block_period < request_timeout:
        raise ValueError(
            f"need 0 < block period ({block_period}) < request timeout ({request_timeout})"
        )
    config: dict[str, Any] = {"chainId": chain_id}
    config.update({fork: 0 for fork in _BLOCK_FORKS + _TIME_FORKS})
    config["zeroBaseFee"] = True
    config["qbft"] = {
        "blockperiodseconds": block_period,
        "epochlength": epoch_length,
        "requesttimeoutseconds": request_timeout,
    }
    return {
        "config": config,
        "nonce": "0x0",
        "timestamp": hex(int(time.time()) if timestamp is None else timestamp),
        "gasLimit": hex(GAS_LIMIT),
        "difficulty": "0x1",
        "mixHash": BFT_MIX_HASH,
        "coinbase": "0x" + "00" * 20,
        "alloc": {deployer.lower().removeprefix("0x"): {"balance": hex(deployer_balance)}},
        "extraData": qbft_extra_data(validators),
    }


@dataclass(frozen=True)
class Layout:
    """Where :func:`generate` puts each file under one directory."""

    root: Path

    @property
    def keys(self) -> Path:
        return self.root / "keys"

    @property
    def worker_keys(self) -> Path:
        return self.root / "worker-keys"

    @property
    def public(self) -> Path:
        return self.root / "public"

    @property
    def genesis(self) -> Path:
        return self.public / "genesis.json"

    @property
    def deployer_key(self) -> Path:
        return self.keys / "deployer.key"

    def validator_key(self, i: int) -> Path:
        return self.keys / f"validator{i}.key"

    def worker_key(self, i: int) -> Path:
        return self.worker_keys / f"worker-{i}.key"


def generate(
    root: str | os.PathLike[str],
    *,
    validators: int = 4,
    workers: int = 2,
    chain_id: int = 2025,
    hosts: Sequence[str] | None = None,
    block_period: int = 2,
) -> list[Node]:
    """Write keys, genesis and peer list under ``root`` (see the module docstring).

    ``hosts`` are the validators' host names or IPs as peers reach them (default
    ``validator1`` ... as in docker-compose.yml); returns the validators in extraData order."""
    if validators < 1:
        raise ValueError(f"validators must be >= 1, got {validators}")
    if workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    hosts = list(hosts) if hosts else [f"validator{i}" for i in range(1, validators + 1)]
    if len(hosts) != validators:
        raise ValueError(f"{validators} validators need {validators} hosts, got {hosts}")
    layout = Layout(Path(root))
    if layout.genesis.exists() or layout.keys.exists():
        raise FileExistsError(
            f"{layout.root} already holds a chain (genesis or keys); remove it to start a new one"
        )
    for i in range(1, validators + 1):
        write_key(layout.validator_key(i))
    deployer = write_key(layout.deployer_key)
    add_worker_keys(layout.root, workers)
    nodes = [node_of(hosts[i - 1], layout.validator_key(i)) for i in range(1, validators + 1)]
    genesis = qbft_genesis(
        [n.address for n in nodes], deployer.address, chain_id=chain_id, block_period=block_period
    )
    layout.public.mkdir(parents=True, exist_ok=True)
    _write_json(layout.genesis, genesis)
    _write_json(layout.public / "static-nodes.json", [n.enode() for n in nodes])
    _write_json(
        layout.public / "validators.json",
        {
            "chain_id": chain_id,
            "deployer": deployer.address,
            "validators": [
                {"host": n.name, "address": n.address, "enode": n.enode()} for n in nodes
            ],
        },
    )
    return nodes


def add_worker_keys(root: str | os.PathLike[str], count: int) -> list[Path]:
    """Make sure ``worker-1.key`` ... ``worker-<count>.key`` exist under ``root``; returns the
    keys created (existing ones are kept: a worker's key is its identity on chain)."""
    layout = Layout(Path(root))
    created = []
    for i in range(1, count + 1):
        if not layout.worker_key(i).exists():
            write_key(layout.worker_key(i))
            created.append(layout.worker_key(i))
    return created


def _write_json(path: Path, doc: Any) -> None:
    path.write_text(json.dumps(doc, indent=2) + "\n")
