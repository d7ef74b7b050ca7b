"""Uploads whose CIDs are known before anything is published (commit-reveal of CIDs).

A CID is public from the moment its content is in a store others read; a worker must commit
it on chain first (TMC.commitCid), or whoever reads it could hand it in ahead of its producer.
:class:`StagedUpload` stands in for a store while a bundle is built (``upload_model``,
``seal_model``): it computes each CID as an IPFS node would (``compute_cid``) and keeps the
bytes; :meth:`StagedUpload.publish` adds them to the real store after the commitment, checking
that the store gives the same CIDs.
"""

from __future__ import annotations

from .dag import compute_cid
from .errors import CIDMismatch


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
