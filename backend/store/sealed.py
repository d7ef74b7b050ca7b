"""Sealed outcomes: a task's model weights readable by its requester only (docs/chain.md,
"Outcomes are public before payment").

The chain stores the CID of the *plaintext* bundle (so provenance, duplicate checks and the
MMC's outcome rule are unchanged), but the worker never uploads the plaintext weights. It
uploads the card (public: the evidence a requester reviews on), a ciphertext of the weights
and an envelope, and names the envelope in the manifest (``"sealed": {file: envelope CID}``).
Knowing the CID on chain therefore gives the card and the weights' hash, not the weights.

The envelope is ECIES over secp256k1, the curve of Ethereum keys: an ephemeral key pair,
ECDH with the requester's public key (its ``outcome_key``, whose address the worker checks
against the task's requester on chain), HKDF-SHA256, AES-256-GCM with the weights' plaintext
CID and the recipient as associated data. Opening checks the decrypted bytes against the
plaintext CID in the manifest, so a wrong key, a tampered ciphertext or a swapped envelope
is an error, never wrong weights. The weights become public when their owner shares the
model: sharing uploads the plaintext, whose CID is the one already in the manifest.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from cryptography.exceptions import InvalidTag
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.ciphers.aead import AESGCM
from cryptography.hazmat.primitives.kdf.hkdf import HKDF
from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat
from eth_utils import keccak, to_checksum_address

from .bundle import (
    BUNDLE_FORMAT,
    MODEL_FILES,
    canonical_json,
    check_model_card,
    fetch_model_file,
    manifest_document,
    model_files,
    read_bundle,
)
from .dag import compute_cid
from .errors import InvalidContent, NotFound, StoreError

SEALED_FORMAT = "drlaas-sealed/1"
#: The bundle file that is sealed; the card stays public.
SEALED_FILE = "model.safetensors"
_HKDF_INFO = b"drlaas-sealed/1 aes-256-gcm"
_MAX_ENVELOPE_BYTES = 4096
_GCM_OVERHEAD = 12 + 16  # nonce + tag


class SealedContent(StoreError):
    """The file is sealed to a recipient and no (or the wrong) private key was given."""


def parse_public_key(value: str | bytes) -> bytes:
    """The 64-byte secp256k1 public key (x || y) of ``0x`` + 128 hex digits (an ``04``
    prefix is accepted); ValueError when it is not hex of that length or not on the curve."""
    if isinstance(value, str):
        text = value[2:] if value[:2].lower() == "0x" else value
        try:
            raw = bytes.fromhex(text)
        except ValueError:
            raise ValueError("expected hex digits") from None
    else:
        raw = bytes(value)
    if len(raw) == 65 and raw[0] == 4:
        raw = raw[1:]
    if len(raw) != 64:
        raise ValueError(f"expected a 64-byte uncompressed secp256k1 public key, got {len(raw)}")
    _curve_point(raw)
    return raw


def _curve_point(pub: bytes) -> ec.EllipticCurvePublicKey:
    try:
        return ec.EllipticCurvePublicKey.from_encoded_point(ec.SECP256K1(), b"\x04" + pub)
    except ValueError:
        raise ValueError("not a point of secp256k1") from None


def public_key_hex(private_key: bytes) -> str:
    """``0x`` + the 64-byte public key of an Ethereum private key (what ``outcome_key`` takes)."""
    priv = ec.derive_private_key(int.from_bytes(private_key, "big"), ec.SECP256K1())
    point = priv.public_key().public_bytes(Encoding.X962, PublicFormat.UncompressedPoint)
    return "0x" + point[1:].hex()


def address_of(pub: bytes) -> str:
    """The Ethereum address of a 64-byte public key (last 20 bytes of its keccak-256)."""
    return to_checksum_address(keccak(pub)[-20:])


def _aead_key(shared: bytes, aad: bytes) -> bytes:
    return HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=_HKDF_INFO + aad).derive(
        shared
    )


def _aad(plain_cid: str, recipient: str) -> bytes:
    return f"{plain_cid}|{recipient.lower()}".encode()


def seal_model(store: Any, model_dir: str | os.PathLike[str], recipient_pub: bytes) -> str:
    """Upload ``model_dir``'s bundle with its weights sealed to ``recipient_pub``; return the
    plaintext bundle's CID (what goes on chain). The plaintext weights are not uploaded."""
    d = Path(model_dir)
    files = {name: (d / name).read_bytes() for name in MODEL_FILES}
    weights = files[SEALED_FILE]
    plain_cid = compute_cid(weights)
    recipient = address_of(recipient_pub)
    eph = ec.generate_private_key(ec.SECP256K1())
    shared = eph.exchange(ec.ECDH(), _curve_point(recipient_pub))
    nonce = os.urandom(12)
    aad = _aad(plain_cid, recipient)
    cipher = nonce + AESGCM(_aead_key(shared, aad)).encrypt(nonce, weights, aad)
    epk = eph.public_key().public_bytes(Encoding.X962, PublicFormat.UncompressedPoint)[1:]
    envelope = {
        "format": SEALED_FORMAT,
        "file": SEALED_FILE,
        "plain": plain_cid,
        "recipient": recipient,
        "epk": "0x" + epk.hex(),
        "cipher": store.add(cipher),
        "cipher_size": len(cipher),
    }
    entries = {
        "model.json": {"cid": store.add(files["model.json"]), "size": len(files["model.json"])},
        SEALED_FILE: {"cid": plain_cid, "size": len(weights)},
    }
    manifest = {
        "format": BUNDLE_FORMAT,
        "files": entries,
        "sealed": {SEALED_FILE: store.add(canonical_json(envelope))},
    }
    return store.add(canonical_json(manifest))


def sealed_envelopes(store: Any, cid: str) -> dict[str, str]:
    """{file name: envelope CID} of bundle ``cid`` ({} for a bundle with nothing sealed);
    InvalidContent when ``cid`` is no bundle manifest (a manifest nested past the JSON
    parser's depth raised RecursionError, a 500 of the gateway's ``POST /models``)."""
    sealed = manifest_document(store, cid).get("sealed")
    if not sealed:
        return {}
    if not isinstance(sealed, dict) or not all(isinstance(v, str) for v in sealed.values()):
        raise InvalidContent(f"bundle {cid}: 'sealed' must map file names to envelope CIDs")
    return dict(sealed)


def read_envelope(store: Any, envelope_cid: str) -> dict[str, Any]:
    """The envelope document, checked field by field."""
    try:
        doc = json.loads(store.get(envelope_cid, max_size=_MAX_ENVELOPE_BYTES))
    except (ValueError, RecursionError):  # RecursionError: nested past the parser's depth
        raise InvalidContent(f"{envelope_cid} is not a JSON envelope") from None
    if not isinstance(doc, dict) or doc.get("format") != SEALED_FORMAT:
        raise InvalidContent(f"{envelope_cid} is not a {SEALED_FORMAT} envelope")
    for key in ("file", "plain", "recipient", "epk", "cipher"):
        if not isinstance(doc.get(key), str):
            raise InvalidContent(f"envelope {envelope_cid}: {key!r} must be a string")
    if not isinstance(doc.get("cipher_size"), int) or doc["cipher_size"] < _GCM_OVERHEAD:
        raise InvalidContent(f"envelope {envelope_cid}: bad cipher_size")
    return doc


def open_sealed(store: Any, bundle_cid: str, name: str, private_key: bytes) -> bytes:
    """The plaintext of file ``name`` of bundle ``bundle_cid``, decrypted with ``private_key``
    and verified against the manifest's plaintext CID; SealedContent when the key is not
    the recipient's, InvalidContent when the envelope or ciphertext was tampered with."""
    files = read_bundle(store, bundle_cid)
    plain_cid, size = files[name]
    envelope_cid = sealed_envelopes(store, bundle_cid).get(name)
    if envelope_cid is None:
        raise InvalidContent(f"bundle {bundle_cid}: {name} is not sealed")
    env = read_envelope(store, envelope_cid)
    if env["file"] != name or env["plain"] != plain_cid:
        raise InvalidContent(f"envelope {envelope_cid} is for another file than {name}")
    if env["cipher_size"] != size + _GCM_OVERHEAD:
        raise InvalidContent(f"envelope {envelope_cid}: cipher_size does not match {size} bytes")
    priv = ec.derive_private_key(int.from_bytes(private_key, "big"), ec.SECP256K1())
    own = address_of(parse_public_key(public_key_hex(private_key)))
    if own.lower() != env["recipient"].lower():
        raise SealedContent(
            f"{name} of {bundle_cid} is sealed to {env['recipient']}; this key is {own}"
        )
    try:
        epk = _curve_point(parse_public_key(env["epk"]))
    except ValueError as exc:
        raise InvalidContent(f"envelope {envelope_cid}: epk {exc}") from None
    cipher = store.get(env["cipher"], max_size=env["cipher_size"])
    aad = _aad(plain_cid, env["recipient"])
    try:
        plain = AESGCM(_aead_key(priv.exchange(ec.ECDH(), epk), aad)).decrypt(
            cipher[:12], cipher[12:], aad
        )
    except InvalidTag:
        raise InvalidContent(
            f"{name} of {bundle_cid}: the ciphertext fails authentication"
        ) from None
    if compute_cid(plain) != plain_cid:
        raise InvalidContent(f"{name} of {bundle_cid}: decrypted bytes do not match {plain_cid}")
    if len(plain) != size:
        raise InvalidContent(
            f"{name} of bundle {bundle_cid} has {len(plain)} bytes, its manifest says {size}"
        )
    return plain


def pull_model_with_key(
    store: Any, cid: str, dest: str | os.PathLike[str], private_key: bytes | None
) -> Path:
    """Both model files of bundle ``cid`` into ``dest``: a sealed file opened from its envelope
    when ``private_key`` is given, every other file from the store (SealedContent for a sealed
    file without a key that its owner has not published)."""
    files = model_files(store, cid)  # exactly the model files, each within its bound
    check_model_card(store, cid, files)  # the card is never sealed
    sealed = sealed_envelopes(store, cid)
    out = Path(dest)
    out.mkdir(parents=True, exist_ok=True)
    for name in MODEL_FILES:
        if name in sealed and private_key is not None:
            _write_new(out / name, open_sealed(store, cid, name, private_key))
            continue
        try:
            fetch_model_file(store, cid, name, files[name], out / name)
        except NotFound:
            if name not in sealed:
                raise
            raise SealedContent(
                f"{name} of {cid} is sealed to the task's requester and not published: give "
                "the requester's key to open it"
            ) from None
    return out


def _write_new(path: Path, data: bytes) -> None:
    """Write ``path`` through a new temporary file beside it, renamed into place: a file
    left at a fixed temporary name (a symlink, say) is never written through."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".part")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def publish_model(store: Any, cid: str, model_dir: str | os.PathLike[str]) -> None:
    """Upload the plaintext files of bundle ``cid`` from ``model_dir`` (the owner sharing a
    sealed outcome); ValueError when a file's CID is not the manifest's."""
    files = read_bundle(store, cid)
    d = Path(model_dir)
    for name, (file_cid, _size) in files.items():
        data = (d / name).read_bytes()
        if compute_cid(data) != file_cid:
            raise ValueError(f"{d / name} is not the {name} of bundle {cid}")
        store.add(data)
