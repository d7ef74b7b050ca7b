"""Uploads whose CIDs are known before anything is published (commit-reveal of CIDs).

A CID is public from the moment its content is in a store others read; a worker must commit
it on chain first (TMC.commitCid), or whoever reads it could hand it in ahead of its producer.
:class:`StagedUpload` stands in for a store while a bundle is built (``upload_model``,
``seal_model``): it computes each CID as an IPFS node would (``compute_cid``) and keeps the
bytes; :meth:`StagedUpload.publish` adds them to the real store after the commitment, checking
that the store gives the same CIDs.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from .dag import compute_cid
from .errors import CIDMismatch

#: The file of a saved upload listing its pieces' CIDs, in order; written last.
ORDER_FILE = "order.json"


class StagedUpload:
    """A write-only store: ``add`` answers the CID and keeps the bytes until :meth:`publish`."""

    def __init__(self) -> None:
        self._pieces: dict[str, bytes] = {}

    def add(self, data: bytes, *, pin: bool = True) -> str:
        cid = compute_cid(bytes(data))
        self._pieces[cid] = bytes(data)
        return cid

    @property
    def cids(self) -> list[str]:
        """The CIDs staged so far, in the order added."""
        return list(self._pieces)

    def publish(self, store: object) -> None:
        """Add every staged piece to ``store`` (its size bound applies), in the order staged.
        :class:`CIDMismatch` if the store answers another CID (a node with other ``add``
        options than ours): the CID committed would then name nothing."""
        for cid, data in self._pieces.items():
            got = store.add(data)  # type: ignore[attr-defined]
            if got != cid:
                raise CIDMismatch(cid, got, "the store's add options differ from compute_cid's")

    def save(self, directory: str | os.PathLike[str]) -> None:
        """Write the staged pieces to ``directory`` (each under its CID, the order file last
        and atomically), so a process killed between committing a CID and publishing it
        publishes the same bytes after a restart: a sealed bundle is encrypted with a fresh
        key, so sealing again would give another CID and need another commitment."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        for cid, data in self._pieces.items():
            _write_atomic(d / cid, data)
        _write_atomic(d / ORDER_FILE, json.dumps(list(self._pieces)).encode())

    @classmethod
    def load(cls, directory: str | os.PathLike[str]) -> StagedUpload:
        """The upload :meth:`save` wrote to ``directory``, every piece checked against its
        CID; ValueError (naming what is wrong) if it is incomplete or damaged."""
        d = Path(directory)
        try:
            order = json.loads((d / ORDER_FILE).read_bytes())
            if not isinstance(order, list) or not all(isinstance(c, str) for c in order):
                raise ValueError(f"{ORDER_FILE} is not a list of CIDs")
            staged = cls()
            for cid in order:
                data = (d / Path(cid).name).read_bytes()
                if compute_cid(data) != cid:
                    raise ValueError(f"piece {cid} does not match its CID")
                staged._pieces[cid] = data
        except (OSError, RecursionError) as exc:
            raise ValueError(f"saved upload in {d} is incomplete: {exc}") from None
        return staged


def _write_atomic(path: Path, data: bytes) -> None:
    """Write ``path`` whole or not at all; a failed write (a full disk) removes its temp file,
    which took the space a retry needs."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        with tmp.open("wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
