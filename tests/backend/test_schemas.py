"""Request field types: what their JSON Schema says is exactly what they accept."""

from __future__ import annotations

import os
import re
from decimal import Decimal

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import TypeAdapter, ValidationError

from backend.schemas.common import CID_PATTERN, MAX_ID, CidStr, Wei
from backend.schemas.users import WorkerCreate
from backend.store.cid import CID, DAG_PB, RAW
from backend.store.errors import InvalidCID


@given(st.from_regex(CID_PATTERN, fullmatch=True))
@settings(max_examples=300, database=None)
def test_every_string_of_the_cid_pattern_is_a_cid_written_the_same(text: str) -> None:
    assert str(CID.parse(text)) == text
    assert TypeAdapter(CidStr).validate_python(text) == text


@pytest.mark.parametrize("codec", [RAW, DAG_PB])
def test_every_cid_the_store_writes_matches_the_pattern(codec: int) -> None:
    for _ in range(200):
        assert re.fullmatch(CID_PATTERN, str(CID(1, codec, os.urandom(32))))


def test_other_cid_forms_are_refused_by_the_declared_pattern() -> None:
    digest = os.urandom(32)
    v0 = str(CID(0, DAG_PB, digest))  # Qm...: the store names it by its v1 form
    for text in (v0, str(CID(1, RAW, digest)).upper()):
        CID.parse(text)  # the store reads each, but the API takes one canonical form
        with pytest.raises(ValidationError):
            TypeAdapter(CidStr).validate_python(text)
    unused_bits_set = "bafkrei" + "a" * 51 + "b"  # no encoder writes it: neither reads it
    with pytest.raises(InvalidCID, match="not canonical base32"):
        CID.parse(unused_bits_set)
    with pytest.raises(ValidationError):
        TypeAdapter(CidStr).validate_python(unused_bits_set)


@pytest.mark.parametrize(("bits", "bound"), [(96, 10**28), (80, 10**24)])
def test_wei_bounds_fit_the_uint_and_survive_a_double(bits: int, bound: int) -> None:
    schema = TypeAdapter(Wei(bits)).json_schema()
    assert schema["maximum"] == bound < 2**bits
    # A JSON tool that reads the bound as a double and writes it back (shortest repr) gets the
    # same bound; 2^96 would come back as 79228162514264340000000000000, above the uint.
    assert int(Decimal(repr(float(bound)))) == bound
    assert int(Decimal(repr(float(2**bits)))) != 2**bits
    TypeAdapter(Wei(bits)).validate_python(bound)
    with pytest.raises(ValidationError):
        TypeAdapter(Wei(bits)).validate_python(bound + 1)
    assert float(MAX_ID) == MAX_ID


def test_worker_domains_are_unique_items() -> None:
    assert WorkerCreate.model_json_schema()["properties"]["domains"]["uniqueItems"] is True
    with pytest.raises(ValidationError):
        WorkerCreate(domains=[3, 3], cpu_cores=1, ram_gb=1)
    assert WorkerCreate(domains=[5, 3], cpu_cores=1, ram_gb=1).domains == [3, 5]
