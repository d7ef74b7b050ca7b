"""UnixFS file DAGs: building them exactly as an IPFS node's ``add`` does, and reading them back
with every block verified.

Add options reproduced (the store's fixed profile, :data:`ADD_PARAMS` for the RPC API):
CIDv1, sha2-256, raw leaves, fixed-size chunker of 262144 bytes, balanced layout with at most 174
links per node. A file of at most one chunk (including the empty file) is its raw leaf; a larger
one is a tree of dag-pb nodes whose ``Data`` is a UnixFS ``File`` message.

Wire formats written here (protobuf, proto2 field numbers):

* PBNode  { 2: repeated PBLink Links; 1: bytes Data }  -- Links are written *before* Data
  (the canonical dag-pb order; a different order would change every CID).
* PBLink  { 1: bytes Hash (binary CID); 2: string Name (always written, empty); 3: uint64 Tsize }
  where Tsize is the total byte size of all blocks under the link.
* UnixFS Data { 1: Type (File = 2); 2: bytes Data (absent for internal nodes);
  3: uint64 filesize; 4: repeated uint64 blocksizes (unpacked, one per link) }.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import BinaryIO

from .cid import CID, DAG_PB, RAW, decode_varint, encode_varint
from .errors import ContentTooLarge, InvalidContent

CHUNK_SIZE = 262_144
"""Default fixed-size chunker of IPFS (``size-262144``)."""
MAX_LINKS = 174
"""Default maximum number of links per node of the balanced layout."""
MAX_READ_LINKS = 1024
"""Most links a node may have when reading: the store builds nodes of :data:`MAX_LINKS`, and
the most an IPFS node makes is 1024 (kubo's ``Import.UnixFSFileMaxLinks`` in the
``unixfs-v1-2025`` profile). More is a DAG made to pile up pending links, refused."""
MAX_BLOCK_SIZE = 2 * 2**20
"""Largest block accepted when reading (IPFS nodes refuse blocks above ~2 MiB as well)."""
MIN_MEAN_LEAF = 16 * 1024
"""Reading ``max_size`` bytes visits at most ``max_blocks(max_size)`` blocks: leaves of 16 KiB
on average or more (IPFS chunkers cut 256 KiB, buzhash and rabin at least 128 KiB), so blocks
that carry no bytes (links of size 0, chains of one-link nodes) cannot make a few kB of DAG
cost millions of reads."""


def max_blocks(max_size: int, min_mean_leaf: int = MIN_MEAN_LEAF) -> int:
    """Blocks ``read_file`` visits at most for a file of at most ``max_size`` bytes: the
    leaves of ``min_mean_leaf`` bytes, as many inner nodes, and some slack for a small file's
    tree."""
    return 16 + 2 * -(-max(max_size, 0) // min_mean_leaf)

ADD_PARAMS = {
    "cid-version": "1",
    "raw-leaves": "true",
    "hash": "sha2-256",
    "chunker": f"size-{CHUNK_SIZE}",
    "trickle": "false",
    "cid-base": "base32",
}
"""Query parameters that make a node's ``/api/v0/add`` build the same DAG as :class:`DagBuilder`."""

# UnixFS Data.Type values
UNIXFS_RAW = 0
UNIXFS_DIRECTORY = 1
UNIXFS_FILE = 2

# protobuf wire types
_VARINT = 0
_LEN = 2


# -- protobuf primitives --------------------------------------------------------------------------
def _key(field_no: int, wire_type: int) -> bytes:
    return encode_varint((field_no << 3) | wire_type)


def _pb_bytes(field_no: int, value: bytes) -> bytes:
    return _key(field_no, _LEN) + encode_varint(len(value)) + value


def _pb_varint(field_no: int, value: int) -> bytes:
    return _key(field_no, _VARINT) + encode_varint(value)


def _pb_fields(buf: bytes) -> Iterator[tuple[int, int, int | bytes]]:
    """Yield (field number, wire type, value) of a protobuf message; only varint and
    length-delimited fields occur in dag-pb/UnixFS, anything else is rejected."""
    pos = 0
    n = len(buf)
    while pos < n:
        key, pos = decode_varint(buf, pos)
        field_no, wire_type = key >> 3, key & 7
        if field_no == 0:
            raise ValueError("protobuf field number 0")
        if wire_type == _VARINT:
            value, pos = decode_varint(buf, pos)
            yield field_no, wire_type, value
        elif wire_type == _LEN:
            length, pos = decode_varint(buf, pos)
            if pos + length > n:
                raise ValueError("length-delimited field runs past the end of the message")
            yield field_no, wire_type, buf[pos : pos + length]
            pos += length
        else:
            raise ValueError(f"unsupported protobuf wire type {wire_type}")


# -- messages --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Link:
    """A child of a dag-pb node: its CID, the byte size of its whole sub-DAG (Tsize) and the
    number of file bytes under it (the parent's UnixFS blocksize entry)."""

    cid: CID
    tsize: int
    filesize: int


@dataclass
class UnixFSData:
    type: int
    data: bytes | None = None
    filesize: int | None = None
    blocksizes: list[int] = field(default_factory=list)

    def encode(self) -> bytes:
        out = _pb_varint(1, self.type)
        if self.data:  # empty data is left out, like the reference importers do
            out += _pb_bytes(2, self.data)
        if self.filesize is not None:
            out += _pb_varint(3, self.filesize)
        for size in self.blocksizes:
            out += _pb_varint(4, size)
        return out

    @classmethod
    def decode(cls, buf: bytes) -> UnixFSData:
        msg = cls(type=-1)
        for no, wt, value in _pb_fields(buf):
            if no == 1 and wt == _VARINT:
                msg.type = int(value)  # type: ignore[arg-type]
            elif no == 2 and wt == _LEN:
                msg.data = bytes(value)  # type: ignore[arg-type]
            elif no == 3 and wt == _VARINT:
                msg.filesize = int(value)  # type: ignore[arg-type]
            elif no == 4 and wt == _VARINT:
                msg.blocksizes.append(int(value))  # type: ignore[arg-type]
            # hashType, fanout, mode, mtime: irrelevant for reading file bytes
        if msg.type < 0:
            raise ValueError("UnixFS Data without Type")
        return msg


def encode_pbnode(links: list[tuple[CID, int]], data: bytes | None) -> bytes:
    """dag-pb node bytes from (child CID, Tsize) pairs and the node's Data."""
    out = bytearray()
    for cid, tsize in links:
        link = _pb_bytes(1, cid.to_bytes()) + _pb_bytes(2, b"") + _pb_varint(3, tsize)
        out += _pb_bytes(2, link)
    if data is not None:
        out += _pb_bytes(1, data)
    return bytes(out)


def decode_pbnode(
    buf: bytes, max_links: int | None = None
) -> tuple[list[tuple[CID, int | None]], bytes | None]:
    """Parse a dag-pb node into ([(child CID, Tsize)], Data); ValueError as soon as it has more
    than ``max_links`` links (when given), before they are all parsed."""
    links: list[tuple[CID, int | None]] = []
    data: bytes | None = None
    for no, wt, value in _pb_fields(buf):
        if no == 2 and wt == _LEN:
            if max_links is not None and len(links) >= max_links:
                raise ValueError(f"more than {max_links} links")
            cid: CID | None = None
            tsize: int | None = None
            for lno, lwt, lvalue in _pb_fields(value):  # type: ignore[arg-type]
                if lno == 1 and lwt == _LEN:
                    cid = CID.parse(bytes(lvalue))  # type: ignore[arg-type]
                elif lno == 3 and lwt == _VARINT:
                    tsize = int(lvalue)  # type: ignore[arg-type]
            if cid is None:
                raise ValueError("dag-pb link without Hash")
            links.append((cid, tsize))
        elif no == 1 and wt == _LEN:
            data = bytes(value)  # type: ignore[arg-type]
        else:
            raise ValueError(f"unexpected dag-pb field {no}")
    return links, data


# -- building --------------------------------------------------------------------------------------
BlockSink = Callable[[CID, bytes], None]


class DagBuilder:
    """Streaming balanced-layout builder: feed chunks, get blocks through ``sink``, then
    :meth:`finish` returns the root CID.

    Equivalent to the reference importer, which groups the leaves into nodes of at most
    ``MAX_LINKS`` children, then groups those nodes the same way, level by level, until one node
    is left. Here each level keeps its pending links and is turned into a node as soon as it
    holds ``MAX_LINKS`` links and another one arrives, so memory stays O(depth x MAX_LINKS)
    whatever the file size.
    """

    def __init__(self, sink: BlockSink | None = None, *, max_links: int = MAX_LINKS) -> None:
        self._sink = sink
        self._max_links = max_links
        self._levels: list[list[Link]] = [[]]
        self._size = 0
        self._leaves = 0
        self._root: CID | None = None

    @property
    def size(self) -> int:
        """File bytes fed so far."""
        return self._size

    def _emit(self, cid: CID, block: bytes) -> None:
        if self._sink is not None:
            self._sink(cid, block)

    def add_chunk(self, chunk: bytes) -> None:
        if self._root is not None:
            raise RuntimeError("DagBuilder already finished")
        if len(chunk) > MAX_BLOCK_SIZE:
            raise ValueError(f"chunk of {len(chunk)} bytes exceeds {MAX_BLOCK_SIZE}")
        cid = CID.for_block(chunk, RAW)
        self._emit(cid, chunk)
        self._size += len(chunk)
        self._leaves += 1
        self._push(0, Link(cid, len(chunk), len(chunk)))

    def _push(self, level: int, link: Link) -> None:
        if level == len(self._levels):
            self._levels.append([])
        pending = self._levels[level]
        if len(pending) == self._max_links:
            self._levels[level] = []
            self._push(level + 1, self._make_node(pending))
        self._levels[level].append(link)

    def _make_node(self, links: list[Link]) -> Link:
        filesize = sum(link.filesize for link in links)
        data = UnixFSData(UNIXFS_FILE, None, filesize, [link.filesize for link in links])
        block = encode_pbnode([(link.cid, link.tsize) for link in links], data.encode())
        cid = CID.for_block(block, DAG_PB)
        self._emit(cid, block)
        return Link(cid, len(block) + sum(link.tsize for link in links), filesize)

    def finish(self) -> CID:
        """Close the remaining levels into nodes; return the root CID."""
        if self._root is not None:
            return self._root
        if self._leaves == 0:  # the empty file is one empty raw leaf
            self.add_chunk(b"")
        level = 0
        while True:
            pending = self._levels[level]
            is_top = level == len(self._levels) - 1
            if is_top and len(pending) == 1:
                self._root = pending[0].cid  # a single leaf stays a raw leaf
                return self._root
            self._levels[level] = []
            self._push(level + 1, self._make_node(pending))
            level += 1


def iter_chunks(source: bytes | BinaryIO, chunk_size: int = CHUNK_SIZE) -> Iterator[bytes]:
    """Fixed-size chunks of bytes or of a binary file object (the last one may be shorter)."""
    if isinstance(source, (bytes, bytearray, memoryview)):
        view = memoryview(source)
        for start in range(0, len(view), chunk_size):
            yield bytes(view[start : start + chunk_size])
        return
    while True:
        buf = bytearray()
        while len(buf) < chunk_size:  # read() may return short counts on pipes
            part = source.read(chunk_size - len(buf))
            if not part:
                break
            buf += part
        if buf:
            yield bytes(buf)
        if len(buf) < chunk_size:
            return


def build_dag(
    chunks: Iterable[bytes], sink: BlockSink | None = None, *, max_size: int | None = None
) -> tuple[CID, int]:
    """Build the DAG of the concatenated chunks; return (root CID, file size). Stops with
    :class:`ContentTooLarge` as soon as more than ``max_size`` bytes have been fed."""
    builder = DagBuilder(sink)
    for chunk in chunks:
        if max_size is not None and builder.size + len(chunk) > max_size:
            raise ContentTooLarge(None, max_size)
        builder.add_chunk(chunk)
    return builder.finish(), builder.size


def compute_cid(data: bytes | BinaryIO) -> str:
    """The CID an IPFS node returns for ``add`` with :data:`ADD_PARAMS` (nothing is stored)."""
    root, _ = build_dag(iter_chunks(data))
    return str(root)


# -- verified reading ------------------------------------------------------------------------------
BlockSource = Callable[[CID, int], bytes]
"""``get_block(cid, max_bytes)``: raw block bytes, not yet verified, at most ``max_bytes`` long
(a source may raise :class:`ContentTooLarge` itself once the limit is passed)."""


def read_file(
    root: CID, get_block: BlockSource, *, max_size: int, min_mean_leaf: int = MIN_MEAN_LEAF
) -> Iterator[bytes]:
    """Yield the bytes of the UnixFS file ``root``, depth first, verifying every block against
    the CID it was fetched by (:class:`CIDMismatch` otherwise).

    Sizes are bounded: the root's declared filesize is checked before any child is fetched, a
    raw root is fetched with ``max_size`` as its limit, and the running total is checked again as
    bytes arrive, so a node lying about sizes cannot make us read more than ``max_size``.
    Nor more blocks than ``max_blocks(max_size, min_mean_leaf)``, and a link below the root
    must carry bytes: :class:`InvalidContent` otherwise (a DAG of empty links would be read
    without end). Pending links are bounded too, as soon as a node is read: at most
    :data:`MAX_READ_LINKS` per node, no more in all than blocks left to read, and no more file
    bytes declared than ``max_size`` leaves (else a chain of 2 MiB nodes of 45,000 links each
    piles up gigabytes of stack before the first byte).
    """
    total = 0
    first = True
    stack: list[tuple[CID, int | None]] = [(root, None)]
    budget = limit_blocks = max_blocks(max_size, min_mean_leaf)
    pending_bytes = 0  # file bytes the links on the stack declare

    def too_many_blocks() -> InvalidContent:
        return InvalidContent(
            f"{root} needs more than {limit_blocks} blocks for at most {max_size} "
            f"bytes (leaves under {min_mean_leaf} bytes on average are not read)"
        )

    while stack:
        cid, expected_size = stack.pop()
        pending_bytes -= expected_size or 0
        budget -= 1
        if budget < 0:
            raise too_many_blocks()
        limit = MAX_BLOCK_SIZE if cid.codec == DAG_PB else min(MAX_BLOCK_SIZE, max_size - total)
        if first and cid.codec == RAW:
            limit = max_size
        block = get_block(cid, limit)
        if len(block) > max(limit, 0):
            raise ContentTooLarge(len(block), limit, "block")
        cid.verify(block, where=f"block {cid} of {root}")
        if cid.codec == RAW:
            chunk = block
        else:
            chunk, children, declared = _file_node(cid, block)
            if first and declared is not None and declared > max_size:
                raise ContentTooLarge(declared, max_size)
            holds = len(chunk) + sum(size or 0 for _, size in children)
            if expected_size is not None and holds != expected_size:
                # compared with what the node holds, declared or not: a node without filesize
                # under a parent giving it 1,000 bytes was read as the 10 it links, no error
                raise InvalidContent(
                    f"node {cid} holds {holds} bytes but its parent says {expected_size}"
                )
            for child, size in children:
                if size == 0:
                    raise InvalidContent(
                        f"{root} links {child} with a size of 0: no file has such a link"
                    )
            if len(stack) + len(children) > budget:  # each pending link costs a block read
                raise too_many_blocks()
            pending_bytes += sum(size or 0 for _, size in children)
            if total + len(chunk) + pending_bytes > max_size:
                raise InvalidContent(
                    f"node {cid} of {root} links {pending_bytes} bytes still to read after "
                    f"{total + len(chunk)}: more than the {max_size} bytes allowed"
                )
            stack.extend(reversed(children))
        first = False
        if expected_size is not None and cid.codec == RAW and len(chunk) != expected_size:
            raise InvalidContent(
                f"leaf {cid} has {len(chunk)} bytes but its parent says {expected_size}"
            )
        if chunk:
            total += len(chunk)
            if total > max_size:
                raise ContentTooLarge(None, max_size)
            yield chunk


def _file_node(cid: CID, block: bytes) -> tuple[bytes, list[tuple[CID, int | None]], int | None]:
    """(inline data, [(child, its file size)], declared filesize) of a UnixFS file node."""
    try:
        links, data = decode_pbnode(block, max_links=MAX_READ_LINKS)
        if data is None:
            raise ValueError("dag-pb node without UnixFS Data")
        fs = UnixFSData.decode(data)
    except ValueError as e:
        raise InvalidContent(f"block {cid} is not a valid UnixFS node: {e}") from None
    if fs.type not in (UNIXFS_FILE, UNIXFS_RAW):
        raise InvalidContent(f"{cid} is a UnixFS node of type {fs.type}, not a file")
    if len(fs.blocksizes) != len(links):  # a size with no link is bytes nobody reads
        raise InvalidContent(
            f"node {cid} has {len(links)} links but {len(fs.blocksizes)} blocksizes"
        )
    inline = fs.data or b""
    if fs.filesize is not None and fs.filesize != len(inline) + sum(fs.blocksizes):
        raise InvalidContent(f"node {cid}: filesize {fs.filesize} != sum of its parts")
    children: list[tuple[CID, int | None]] = [
        (child, size) for (child, _), size in zip(links, fs.blocksizes, strict=True)
    ]
    return inline, children, fs.filesize
