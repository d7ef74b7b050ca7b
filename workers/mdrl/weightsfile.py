"""Is an untrusted ``model.safetensors`` a safetensors file a worker can load? Checked without
loading a tensor, by the gateway before it lists or accepts a model (``backend.api.bundles``)
and by a worker before it loads an expert (``workers.daemon.experts``).

The first 8 bytes are a little-endian header length, which must fit the file and
:data:`MAX_HEADER_BYTES`; only when it does not is a pickle or a zip archive (``torch.save``)
named by its first bytes (a valid file with a 128-byte header also starts with 0x80, as a
pickle does). Then the ``safetensors`` library parses the header and checks every tensor's
byte range against its dtype and shape, and that the ranges cover the data exactly. At least
one tensor, none empty, every dtype one the workers load.
"""

from __future__ import annotations

import struct
from pathlib import Path

from safetensors import SafetensorError, safe_open

MAX_WEIGHTS_BYTES = 64 * 2**20
"""Bound on a model's weights file (the zoo's largest model is ~0.1 MiB)."""
MAX_HEADER_BYTES = 1 << 20
"""Bound on the JSON header of a safetensors file (a model's is a few kB)."""
DTYPES = frozenset({"F64", "F32", "F16", "BF16", "I64", "I32", "I16", "I8", "U8", "BOOL"})
"""The tensor dtypes a worker loads."""
WEIGHTS = "model.safetensors"

Tensors = dict[str, tuple[str, tuple[int, ...]]]
"""{tensor name: (dtype, shape)} of a file's header."""


class WeightsFileError(ValueError):
    """Not a loadable safetensors file: ``rule`` names the check (``weights_not_safetensors``,
    ``weights_empty``, ``weights_dtype_unsupported``), the message what is wrong."""

    def __init__(self, rule: str, msg: str) -> None:
        super().__init__(msg)
        self.rule = rule


def check_head(head: bytes, size: int) -> None:
    """The first 8 bytes of a ``size``-byte weights file (module docstring): can be checked
    before the rest of the file is fetched."""
    n = struct.unpack("<Q", head)[0] if len(head) == 8 else None
    if n is not None and n <= min(MAX_HEADER_BYTES, size - 8):
        return
    if head[:1] == b"\x80" or head[:2] == b"PK":
        kind = "a pickle" if head[:1] == b"\x80" else "a zip archive (torch.save)"
        raise WeightsFileError(
            "weights_not_safetensors",
            f"{WEIGHTS} is {kind}, not safetensors: refused (models are never unpickled)",
        )
    if n is None:
        raise WeightsFileError(
            "weights_not_safetensors", f"{WEIGHTS} ({size} bytes) is too short to be safetensors"
        )
    raise WeightsFileError(
        "weights_not_safetensors",
        f"{WEIGHTS}: safetensors header length {n} does not fit the file ({size} bytes) "
        f"or the bound of {MAX_HEADER_BYTES} bytes",
    )


def check_weights_file(path: Path) -> Tensors:
    """The tensors of a loadable weights file at ``path``; :class:`WeightsFileError` if it is
    not one (module docstring). No tensor data is read."""
    size = path.stat().st_size
    with path.open("rb") as f:
        check_head(f.read(8), size)
    try:
        with safe_open(str(path), framework="np") as f:
            tensors = {}
            for name in f.keys():  # noqa: SIM118 - a safe_open handle, not a dict
                piece = f.get_slice(name)
                tensors[name] = (str(piece.get_dtype()), tuple(int(d) for d in piece.get_shape()))
    except SafetensorError as exc:
        raise WeightsFileError(
            "weights_not_safetensors", f"{WEIGHTS} is not a valid safetensors file: {exc}"
        ) from None
    if not tensors:
        raise WeightsFileError("weights_empty", f"{WEIGHTS} holds no tensor")
    for name, (dtype, shape) in tensors.items():
        if dtype not in DTYPES:
            raise WeightsFileError(
                "weights_dtype_unsupported",
                f"{WEIGHTS}: tensor {name!r} has dtype {dtype}, the workers load {sorted(DTYPES)}",
            )
        if 0 in shape:
            raise WeightsFileError(
                "weights_empty", f"{WEIGHTS}: tensor {name!r} is empty (shape {list(shape)})"
            )
    return tensors
