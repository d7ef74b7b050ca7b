"""The generated consortium: keys, QBFT genesis and enode URLs, decoded independently of the
code that wrote them (rlp, eth_keys and keccak straight from the key files)."""

from __future__ import annotations

import json
import re
import stat
from pathlib import Path

import pytest
import rlp
from eth_keys import keys as eth_keys
from eth_utils import keccak, to_checksum_address

from backend.chain.consortium import (
    BFT_MIX_HASH,
    Layout,
    add_worker_keys,
    generate,
    qbft_extra_data,
    qbft_genesis,
)


def key_of(path: Path) -> eth_keys.PrivateKey:
    text = path.read_text().strip()
    assert re.fullmatch(r"0x[0-9a-f]{64}", text), f"{path} is not Besu's key-file format"
    return eth_keys.PrivateKey(bytes.fromhex(text[2:]))


def genesis_of(layout: Layout) -> dict:
    return json.loads(layout.genesis.read_text())


def test_keys_are_owner_only_and_distinct(consortium: Layout) -> None:
    files = sorted(consortium.keys.glob("*.key")) + sorted(consortium.worker_keys.glob("*.key"))
    names = [f.name for f in files]
    assert names == [
        "deployer.key",
        "validator1.key",
        "validator2.key",
        "validator3.key",
        "validator4.key",
        "worker-1.key",
        "worker-2.key",
    ]
    for f in files:
        assert stat.S_IMODE(f.stat().st_mode) == 0o600, f
    assert len({key_of(f).to_hex() for f in files}) == len(files)


def test_extra_data_lists_the_validators_of_the_key_files_in_order(consortium: Layout) -> None:
    vanity, validators, vote, round_, seals = rlp.decode(
        bytes.fromhex(genesis_of(consortium)["extraData"][2:])
    )
    assert vanity == b"\x00" * 32
    expected = [
        key_of(consortium.validator_key(i)).public_key.to_canonical_address() for i in range(1, 5)
    ]
    assert validators == expected
    # QBFT (Besu QbftExtraDataCodec): no vote is an empty list, round 0 the empty scalar,
    # and the genesis block carries no committed seals.
    assert vote == [] and round_ == b"" and seals == []


def test_chain_config_has_qbft_cancun_and_free_gas(consortium: Layout) -> None:
    g = genesis_of(consortium)
    c = g["config"]
    assert c["chainId"] == 4242
    assert c["londonBlock"] == 0 and c["shanghaiTime"] == 0 and c["cancunTime"] == 0
    assert c["zeroBaseFee"] is True
    assert c["qbft"] == {"blockperiodseconds": 2, "epochlength": 30000, "requesttimeoutseconds": 4}
    assert int(g["gasLimit"], 16) == 30_000_000
    assert g["mixHash"] == BFT_MIX_HASH and int(g["difficulty"], 16) == 1


def test_alloc_funds_the_deployer_only(consortium: Layout) -> None:
    deployer = key_of(consortium.deployer_key).public_key.to_checksum_address()
    alloc = genesis_of(consortium)["alloc"]
    assert [to_checksum_address("0x" + a.removeprefix("0x")) for a in alloc] == [deployer]
    assert int(next(iter(alloc.values()))["balance"], 16) >= 10**18


def test_enode_urls_derive_from_the_validator_keys(consortium: Layout) -> None:
    enodes = json.loads((consortium.public / "static-nodes.json").read_text())
    listed = json.loads((consortium.public / "validators.json").read_text())
    assert [v["enode"] for v in listed["validators"]] == enodes
    for i, url in enumerate(enodes, start=1):
        m = re.fullmatch(r"enode://([0-9a-f]{128})@([^:]+):(\d+)", url)
        assert m, url
        public = bytes.fromhex(m.group(1))
        key = key_of(consortium.validator_key(i))
        assert public == key.public_key.to_bytes()
        # The node address (keccak of the public key) is the validator address of extraData.
        assert to_checksum_address(keccak(public)[-20:]) == listed["validators"][i - 1]["address"]
        assert (m.group(2), m.group(3)) == (f"validator{i}", "30303")


def test_hosts_name_the_peers(tmp_path: Path) -> None:
    generate(tmp_path, validators=2, workers=0, hosts=["10.0.0.1", "member-b.example"])
    enodes = json.loads((tmp_path / "public" / "static-nodes.json").read_text())
    assert [e.split("@")[1] for e in enodes] == ["10.0.0.1:30303", "member-b.example:30303"]
    with pytest.raises(ValueError, match="3 validators need 3 hosts"):
        generate(tmp_path / "other", validators=3, hosts=["a", "b"])


def test_generating_again_never_replaces_keys(consortium: Layout) -> None:
    before = consortium.validator_key(1).read_text()
    with pytest.raises(FileExistsError, match="already holds a chain"):
        generate(consortium.root, validators=4)
    assert consortium.validator_key(1).read_text() == before


def test_worker_keys_are_added_never_replaced(consortium: Layout) -> None:
    first = consortium.worker_key(1).read_text()
    created = add_worker_keys(consortium.root, 4)
    assert created == [consortium.worker_key(3), consortium.worker_key(4)]
    assert consortium.worker_key(1).read_text() == first
    assert add_worker_keys(consortium.root, 4) == []


def test_bad_parameters_are_named() -> None:
    with pytest.raises(ValueError, match="20 bytes"):
        qbft_extra_data(["0x1234"])
    with pytest.raises(ValueError, match="at least one validator"):
        qbft_extra_data([])
    with pytest.raises(ValueError, match="block period"):
        qbft_genesis(["0x" + "11" * 20], "0x" + "22" * 20, chain_id=1, block_period=4)
