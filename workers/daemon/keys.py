"""Local key files: one hex private key per file, readable by its owner only.

The CLI and the worker daemon sign with these (platform.md, "Signing"); the gateway never sees
them outside development mode.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from eth_account import Account
from eth_account.signers.local import LocalAccount


def load_key(path: str | os.PathLike[str]) -> LocalAccount:
    """The account in key file ``path`` (hex key, optionally 0x-prefixed, or JSON
    ``{"private_key": ...}``); errors name the file."""
    p = Path(path).expanduser()
    if not p.is_file():
        raise FileNotFoundError(
            f"key file not found: {p} (create one with `drlaas worker "
            f"register --key {p}` or `drlaas task submit --key {p}`)"
        )
    text = p.read_text().strip()
    if text.startswith("{"):
        try:
            text = str(json.loads(text)["private_key"])
        except (ValueError, KeyError):
            raise ValueError(f"key file {p}: JSON without a 'private_key' field") from None
    try:
        return Account.from_key(text)
    except Exception:  # noqa: BLE001 - eth_account raises several types
        raise ValueError(f"key file {p}: not a 32-byte hex private key") from None


def create_key(path: str | os.PathLike[str], private_key: str | None = None) -> LocalAccount:
    """Write a new (or the given) private key to ``path`` with mode 0600; refuses to overwrite."""
    p = Path(path).expanduser()
    if p.exists():
        raise FileExistsError(f"key file already exists: {p}")
    account = Account.from_key(private_key) if private_key else Account.create()
    p.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write("0x" + bytes(account.key).hex() + "\n")
    return account


def load_or_create_key(path: str | os.PathLike[str]) -> LocalAccount:
    p = Path(path).expanduser()
    return load_key(p) if p.exists() else create_key(p)
