"""The check of an untrusted weights file (workers.mdrl.weightsfile), shared by the gateway and
the workers: by header length first, so a valid file whose header length starts with a
pickle's or a zip's first bytes is not refused as one."""

from __future__ import annotations

import json
import pickle
import struct
from pathlib import Path

import numpy as np
import pytest
from safetensors.numpy import save_file

from workers.mdrl.weightsfile import WeightsFileError, check_weights_file


def padded_to(header_len: int, path: Path) -> Path:
    """A valid safetensors file whose JSON header is exactly ``header_len`` bytes."""
    tensor = np.arange(6, dtype=np.float32).reshape(2, 3)
    meta = {"t": {"dtype": "F32", "shape": [2, 3], "data_offsets": [0, tensor.nbytes]}}
    raw = json.dumps(meta).encode()
    assert len(raw) <= header_len
    raw += b" " * (header_len - len(raw))  # the format allows trailing spaces
    path.write_bytes(struct.pack("<Q", header_len) + raw + tensor.tobytes())
    return path


@pytest.mark.parametrize("header_len", [128, 128 + 256, 0x4B50])  # 0x80..., "PK" little-endian
def test_a_valid_file_whose_length_looks_like_a_pickle_or_a_zip_is_accepted(tmp_path, header_len):
    tensors = check_weights_file(padded_to(header_len, tmp_path / "w.safetensors"))
    assert tensors == {"t": ("F32", (2, 3))}


def test_pickles_archives_and_broken_files_are_refused_by_name(tmp_path):
    cases = {
        pickle.dumps({"evil": print}): "is a pickle",
        b"PK\x03\x04" + b"\x00" * 60: "zip archive",
        b"\x01\x02": "too short",
        struct.pack("<Q", 10**18) + b"{}": "does not fit",
    }
    for raw, words in cases.items():
        path = tmp_path / "w.safetensors"
        path.write_bytes(raw)
        with pytest.raises(WeightsFileError, match=words) as err:
            check_weights_file(path)
        assert err.value.rule == "weights_not_safetensors"
    ok = tmp_path / "ok.safetensors"
    save_file({"a": np.zeros((2,), np.float32)}, str(ok))
    broken = ok.read_bytes()[:-1]  # one byte short of its last tensor's range
    (tmp_path / "b.safetensors").write_bytes(broken)
    with pytest.raises(WeightsFileError, match="not a valid safetensors"):
        check_weights_file(tmp_path / "b.safetensors")
    save_file({"a": np.zeros((0, 3), np.float32)}, str(ok))
    with pytest.raises(WeightsFileError, match="empty") as err:
        check_weights_file(ok)
    assert err.value.rule == "weights_empty"


def test_load_weights_checks_size_and_header_before_reading(tmp_path) -> None:
    """`drlaas eval` read a 256 MB weights file whole (1.25 GB of RAM) before finding it was
    not the model's; a pickle got past to the safetensors parser's own message."""
    import pytest

    from workers.mdrl.modelio import load_weights
    from workers.mdrl.weightsfile import MAX_WEIGHTS_BYTES

    big = tmp_path / "big"
    big.mkdir()
    with (big / "model.safetensors").open("wb") as f:  # sparse: nothing is written
        f.truncate(MAX_WEIGHTS_BYTES + 1)
    with pytest.raises(ValueError, match="more than a model's weights may be"):
        load_weights(big)
    pickled = tmp_path / "pickled"
    pickled.mkdir()
    (pickled / "model.safetensors").write_bytes(b"\x80\x04\x95" + b"\x00" * 64)
    with pytest.raises(ValueError, match="pickle"):
        load_weights(pickled)
