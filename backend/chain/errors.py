"""Custom Solidity errors as typed Python exceptions.

web3's ``ContractCustomError`` carries only the raw revert data; here the 4-byte selector
is looked up among the errors of every built ABI and the arguments are decoded, so callers
write ``except errors.get("TasksNotOfferedWorker") as e: e.args_dict["worker"]``.
Each error name maps to one subclass of :class:`ContractError`, created once; importing a
name from this module (``from backend.chain.errors import TasksNotOfferedWorker``) works too.
"""

from __future__ import annotations

import functools
from typing import Any

from eth_abi import decode
from eth_utils import keccak, to_checksum_address

PANIC_CODES = {
    0x01: "assert failed",
    0x11: "arithmetic overflow or underflow",
    0x12: "division or modulo by zero",
    0x21: "invalid enum value",
    0x32: "array index out of bounds",
    0x41: "out of memory",
}


class ContractError(Exception):
    """A contract call or transaction reverted with a known custom error."""

    name = "ContractError"
    inputs: tuple[tuple[str, str], ...] = ()

    def __init__(self, args_dict: dict[str, Any] | None = None, data: bytes = b""):
        self.args_dict = dict(args_dict or {})
        self.data = data
        shown = ", ".join(f"{k}={_show(v)}" for k, v in self.args_dict.items())
        super().__init__(f"{self.name}({shown})")


class UnknownRevert(ContractError):
    """Revert data that matches no error of our ABIs (or an empty revert)."""

    name = "UnknownRevert"


class RevertString(ContractError):
    """``Error(string)``: a revert with a message (not used by our contracts)."""

    name = "Error"
    inputs = (("message", "string"),)


class Panic(ContractError):
    """``Panic(uint256)``: overflow, division by zero, bad index, failed assert."""

    name = "Panic"
    inputs = (("code", "uint256"),)


def _show(v: Any) -> str:
    return "0x" + v.hex() if isinstance(v, bytes) else repr(v)


def _canonical(inp: dict[str, Any]) -> str:
    t = inp["type"]
    if t.startswith("tuple"):
        return "(" + ",".join(_canonical(c) for c in inp["components"]) + ")" + t[5:]
    return t


@functools.cache
def _registry() -> dict[bytes, type[ContractError]]:
    from .artifacts import all_abis

    reg: dict[bytes, type[ContractError]] = {
        keccak(text="Error(string)")[:4]: RevertString,
        keccak(text="Panic(uint256)")[:4]: Panic,
    }
    for abi in all_abis().values():
        for item in abi:
            if item.get("type") != "error":
                continue
            types = [_canonical(i) for i in item["inputs"]]
            sel = keccak(text=f"{item['name']}({','.join(types)})")[:4]
            if sel in reg:
                continue
            reg[sel] = type(
                item["name"],
                (ContractError,),
                {
                    "name": item["name"],
                    "inputs": tuple(
                        (i["name"], t) for i, t in zip(item["inputs"], types, strict=True)
                    ),
                    "__doc__": f"Custom error {item['name']}({', '.join(types)}).",
                    "__module__": __name__,
                },
            )
    return reg


@functools.cache
def _by_name() -> dict[str, type[ContractError]]:
    return {cls.name: cls for cls in _registry().values()}


def get(name: str) -> type[ContractError]:
    """The exception class for custom error ``name``; KeyError lists the known names."""
    try:
        return _by_name()[name]
    except KeyError:
        raise KeyError(f"no custom error {name!r}; known: {sorted(_by_name())}") from None


def selectors() -> dict[str, str]:
    """error signature name -> 0x selector, for documentation and the indexer."""
    return {cls.name: "0x" + sel.hex() for sel, cls in _registry().items()}


def decode_revert(data: bytes | str | None) -> ContractError:
    """Turn raw revert data into the matching typed exception instance."""
    if isinstance(data, str):
        data = bytes.fromhex(data[2:] if data.startswith("0x") else data)
    data = data or b""
    cls = _registry().get(data[:4])
    if cls is None:
        return UnknownRevert({"data": data}, data)
    values = decode([t for _, t in cls.inputs], data[4:]) if cls.inputs else ()
    args = {
        n: to_checksum_address(v) if t == "address" else v
        for (n, t), v in zip(cls.inputs, values, strict=True)
    }
    return cls(args, data)


def __getattr__(name: str) -> type[ContractError]:
    if name.startswith("_"):
        raise AttributeError(name)
    try:
        return get(name)
    except KeyError as e:
        raise AttributeError(str(e)) from None
