"""Content identifiers (CIDs) as IPFS writes them, for the two block kinds a UnixFS file uses.

A CIDv1 is ``varint(1) || varint(codec) || multihash`` where the multihash is
``varint(0x12 = sha2-256) || varint(32) || sha256(block)``; its text form is multibase
base32 (prefix ``b``, lower case, no padding). A CIDv0 is the bare multihash of a dag-pb block in
base58btc (``Qm...``). Only sha2-256 with codecs raw (0x55) and dag-pb (0x70) is supported:
that is all the store writes, and refusing the rest keeps verification simple and strict.
"""

from __future__ import annotations

import base64
import hashlib
from dataclasses import dataclass

from .errors import CIDMismatch, InvalidCID

RAW = 0x55
"""Multicodec of a raw block (a file chunk stored as is)."""
DAG_PB = 0x70
"""Multicodec of a dag-pb (MerkleDAG protobuf) block: the UnixFS internal nodes."""
SHA2_256 = 0x12
"""Multihash code of sha2-256."""

MAX_CID_TEXT = 100
"""Longest CID text parsed (surrounding whitespace aside): a CID of the kinds above is 59
characters in base32, 51 in base58btc, 46 as a CIDv0. Longer text is refused before it is
decoded: base58 decoding takes time quadratic in the length (300 kB of ``z2222...``, a
task description any user can put on chain, took 17 s), and an error names the input by
its first characters only."""
MAX_CID_SHOWN = 80
"""Characters of an invalid CID's ``repr`` that its error message shows."""

_CODEC_NAMES = {RAW: "raw", DAG_PB: "dag-pb"}
_B58_ALPHABET = "123456789ABCDEFGHJKLMNPQRSTUVWXYZabcdefghijkmnopqrstuvwxyz"
_B58_INDEX = {c: i for i, c in enumerate(_B58_ALPHABET)}


# -- unsigned LEB128 varints (multiformats and protobuf use the same encoding) ---------------------
def encode_varint(n: int) -> bytes:
    """Unsigned LEB128: 7 bits per byte, high bit set on every byte but the last."""
    if n < 0:
        raise ValueError(f"varint must be non-negative, got {n}")
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def decode_varint(buf: bytes | memoryview, pos: int = 0) -> tuple[int, int]:
    """Decode a varint at ``pos``; return (value, next position). At most 9 bytes (63 bits),
    so hostile input cannot make us build huge integers."""
    result = 0
    shift = 0
    for i in range(9):
        if pos + i >= len(buf):
            raise ValueError("truncated varint")
        b = buf[pos + i]
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            if i > 0 and b == 0:
                raise ValueError("non-minimal varint")
            return result, pos + i + 1
        shift += 7
    raise ValueError("varint longer than 9 bytes")


# -- multibase -------------------------------------------------------------------------------------
def _b32encode(data: bytes) -> str:
    return base64.b32encode(data).decode("ascii").rstrip("=").lower()


def _b32decode(text: str) -> bytes:
    """The bytes of unpadded lowercase base32 ``text``; ValueError for a text no byte string
    encodes to (a length RFC 4648 never produces, or unused low bits of the last character
    set): those would let four texts name one CID, and the chain compares CID texts."""
    pad = "=" * (-len(text) % 8)
    raw = base64.b32decode(text.upper() + pad)
    if _b32encode(raw) != text:
        raise ValueError("not canonical base32 (a length or trailing bits no encoder writes)")
    return raw


def _b58encode(data: bytes) -> str:
    n = int.from_bytes(data, "big")
    out = []
    while n:
        n, r = divmod(n, 58)
        out.append(_B58_ALPHABET[r])
    zeros = len(data) - len(data.lstrip(b"\0"))
    return "1" * zeros + "".join(reversed(out))


def _b58decode(text: str) -> bytes:
    n = 0
    for c in text:
        if c not in _B58_INDEX:
            raise ValueError(f"invalid base58 character {c!r}")
        n = n * 58 + _B58_INDEX[c]
    zeros = len(text) - len(text.lstrip("1"))
    body = n.to_bytes((n.bit_length() + 7) // 8, "big") if n else b""
    return b"\0" * zeros + body


# -- CID -------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CID:
    """A parsed CID: version, codec and the sha2-256 digest of the block it names."""

    version: int
    codec: int
    digest: bytes

    def __post_init__(self) -> None:
        if self.version not in (0, 1):
            raise InvalidCID(f"unsupported CID version {self.version}")
        if self.codec not in _CODEC_NAMES:
            raise InvalidCID(f"unsupported CID codec 0x{self.codec:x} (only raw and dag-pb)")
        if self.version == 0 and self.codec != DAG_PB:
            raise InvalidCID("a CIDv0 is always dag-pb")
        if len(self.digest) != 32:
            raise InvalidCID(f"sha2-256 digest must be 32 bytes, got {len(self.digest)}")

    # construction
    @classmethod
    def for_block(cls, block: bytes, codec: int, version: int = 1) -> CID:
        """The CID of ``block`` (sha2-256) with the given codec."""
        return cls(version, codec, hashlib.sha256(block).digest())

    @classmethod
    def parse(cls, value: str | bytes | CID) -> CID:
        """Parse a CID from text (``b...`` base32 v1, ``z...`` base58btc v1, ``Qm...`` v0) or
        binary; raise :class:`InvalidCID` naming the input otherwise."""
        if isinstance(value, CID):
            return value
        try:
            if isinstance(value, (bytes, bytearray, memoryview)):
                cid, end = cls.from_bytes(bytes(value))
                if end != len(value):
                    raise ValueError("trailing bytes after CID")
                return cid
            text = value.strip()
            if len(text) > MAX_CID_TEXT:
                raise ValueError(
                    f"{len(text)} characters, longer than any CID ({MAX_CID_TEXT} at most)"
                )
            if len(text) == 46 and text.startswith("Qm"):
                raw = _b58decode(text)
            elif text[:1] == "b":
                raw = _b32decode(text[1:])
            elif text[:1] == "B":
                raw = _b32decode(text[1:].lower())
            elif text[:1] == "z":
                raw = _b58decode(text[1:])
            else:
                raise ValueError("unknown multibase prefix (expected b..., z... or Qm...)")
            cid, end = cls.from_bytes(raw)
            if end != len(raw):
                raise ValueError("trailing bytes after CID")
            return cid
        except (InvalidCID, ValueError, TypeError, AttributeError) as e:
            raise InvalidCID(f"invalid CID {_shown(value)}: {e}") from None

    @classmethod
    def from_bytes(cls, buf: bytes, pos: int = 0) -> tuple[CID, int]:
        """Decode a binary CID starting at ``pos``; return (cid, end position)."""
        if buf[pos : pos + 2] == bytes([SHA2_256, 32]):  # CIDv0: a bare sha2-256 multihash
            digest = bytes(buf[pos + 2 : pos + 34])
            if len(digest) != 32:
                raise InvalidCID("truncated CIDv0 multihash")
            return cls(0, DAG_PB, digest), pos + 34
        try:
            version, pos = decode_varint(buf, pos)
            codec, pos = decode_varint(buf, pos)
            mh_code, pos = decode_varint(buf, pos)
            mh_len, pos = decode_varint(buf, pos)
        except ValueError as e:
            raise InvalidCID(str(e)) from None
        if version != 1:
            raise InvalidCID(f"unsupported CID version {version}")
        if mh_code != SHA2_256:
            raise InvalidCID(f"unsupported multihash 0x{mh_code:x} (only sha2-256)")
        digest = bytes(buf[pos : pos + mh_len])
        if mh_len != 32 or len(digest) != 32:
            raise InvalidCID("bad sha2-256 digest length")
        return cls(1, codec, digest), pos + 32

    # encoding
    @property
    def multihash(self) -> bytes:
        return bytes([SHA2_256, 32]) + self.digest

    def to_bytes(self) -> bytes:
        """Binary form, as embedded in dag-pb links."""
        if self.version == 0:
            return self.multihash
        return encode_varint(1) + encode_varint(self.codec) + self.multihash

    def __str__(self) -> str:
        if self.version == 0:
            return _b58encode(self.multihash)
        return "b" + _b32encode(self.to_bytes())

    def v1(self) -> CID:
        """The same block named as CIDv1 (the store's canonical text form)."""
        return CID(1, self.codec, self.digest)

    @property
    def codec_name(self) -> str:
        return _CODEC_NAMES[self.codec]

    # verification
    def verify(self, block: bytes, where: str = "") -> None:
        """Raise :class:`CIDMismatch` unless ``block`` hashes to this CID."""
        digest = hashlib.sha256(block).digest()
        if digest != self.digest:
            actual = CID(self.version, self.codec, digest)
            raise CIDMismatch(str(self), str(actual), where)


def _shown(value: object) -> str:
    """``repr(value)``, cut to :data:`MAX_CID_SHOWN` characters with its length said."""
    text = repr(value)
    if len(text) <= MAX_CID_SHOWN:
        return text
    size = f" ({len(value)} long)" if isinstance(value, str | bytes | bytearray) else ""
    return f"{text[:MAX_CID_SHOWN]}...{size}"


def cid_key(cid: str | CID) -> str:
    """Canonical text key (CIDv1 base32) so ``Qm...``/``z...``/``b...`` spellings of one block
    map to one file and one pin."""
    return str(CID.parse(cid).v1())
