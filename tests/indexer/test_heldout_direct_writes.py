"""Held-out: what a transaction signed by anyone straight to the contracts (no gateway, no
pydantic) puts in the index. The contracts take any bytes as a string, so a description that
is not UTF-8 is on the chain like any other."""

from __future__ import annotations

from typing import Any

from eth_abi import encode
from eth_utils import function_signature_to_4byte_selector
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from backend.db import models as m
from backend.indexer import Indexer
from backend.services.chain import ChainService
from tests.gateway.test_indexer import _chain_events, _indexed, any_sessions

__all__ = ["any_sessions"]

NOT_UTF8 = b"task \xff\xfe \xed\xa0\x80 end"  # a stray byte, and a UTF-8-encoded lone surrogate
TASK_PARAMS = "(uint32,uint8,uint32,uint32,uint32,uint32,uint40,string)"


def send(service: ChainService, sender: str, to: str, data: bytes, value: int = 0) -> None:
    """Sign and send ``data`` to ``to`` from ``sender`` as its own transaction; assert it mined."""
    w3 = service.chain.w3
    with service.lock:
        tx = {
            "to": to,
            "data": data,
            "value": value,
            "gas": 3_000_000,
            "chainId": service.chain.chain_id,
            "nonce": w3.eth.get_transaction_count(sender),
            "maxFeePerGas": 2 * w3.eth.get_block("latest")["baseFeePerGas"],
            "maxPriorityFeePerGas": 0,
        }
        signed = service.chain._keys[sender].sign_transaction(tx)
        receipt = w3.eth.wait_for_transaction_receipt(
            w3.eth.send_raw_transaction(signed.raw_transaction)
        )
    assert receipt["status"] == 1


def add_task_calldata(description: bytes, duration: int = 3_600) -> bytes:
    """addTask(domain 0, one worker) with ``description`` as its raw bytes (``string`` and
    ``bytes`` share their ABI encoding)."""
    args = encode([TASK_PARAMS.replace("string", "bytes")], [(0, 1, 0, 0, 0, 0, duration,
                                                              description)])
    return function_signature_to_4byte_selector(f"addTask({TASK_PARAMS})") + args


def add_model_calldata(cid: str, description: bytes, env: list[int]) -> bytes:
    args = encode(["string", "bytes", "uint32", "uint32[]"], [cid, description, 0, env])
    return function_signature_to_4byte_selector("addModel(string,string,uint32,uint32[])") + args


def test_descriptions_that_are_not_utf8_never_stop_the_index(
    service: ChainService, any_sessions: sessionmaker[Session]
) -> None:
    """A task and a model described by bytes that are not UTF-8 (signed straight to the TMC and
    MMC) are indexed with U+FFFD in their place, and the task posted after them too: before,
    decoding the first such log raised, every poll failed at its block, and no later event
    was ever indexed."""
    p, keys = service.platform, service.demo_keys
    assert keys is not None
    req, worker = keys.address("user1"), keys.address("user2")
    cid = "bafkreihdwdcefgh4dqkjv67uzcmw7ojee6xedzdetojuzjevtenxquvyku"
    with service.lock:
        p.umc.add_requester(req)
        p.umc.add_worker(worker, [0], 4, 8, 0)
        p.tmc.commit_cid(worker, cid)
    send(service, req, p.tmc.address, add_task_calldata(NOT_UTF8), value=10**12)
    send(service, worker, p.mmc.address, add_model_calldata(cid, b"model \xc3(", [8, 8, 2, 0]))
    with service.lock:
        later, _ = p.tmc.add_task(req, domain=0, num_workers=1, reward=10**12, duration=3_600,
                                  description="posted after")
    Indexer(service, any_sessions).poll()

    assert _indexed(any_sessions) == _chain_events(service)
    with any_sessions() as s:
        tasks = {t.id: t.description for t in s.scalars(select(m.TaskRow))}
        models = [(r.cid, r.description) for r in s.scalars(select(m.ModelRow))]
        added: Any = s.scalars(select(m.ChainEvent.args).where(m.ChainEvent.name == "TaskAdded")
                               .order_by(m.ChainEvent.block_number)).first()
    assert tasks == {later - 1: NOT_UTF8.decode(errors="replace"), later: "posted after"}
    assert "\ufffd" in tasks[later - 1] and not any(0xD800 <= ord(c) < 0xE000
                                                     for c in tasks[later - 1])
    assert models == [(cid, "model \ufffd(")]
    assert added["description"] == tasks[later - 1]


def test_a_worker_reads_a_description_not_utf8_as_the_index_does(service: ChainService) -> None:
    """The worker daemon reads an offered task's spec CID from its TaskAdded event: a
    description that is not UTF-8 reads as U+FFFD (no CID: the offer is declined), and a CID
    as it is. Before, web3's strict decoding raised, so a requester could leave every offer of
    its task unanswered until it expired."""
    from workers.daemon.links import task_spec_cid

    p, keys = service.platform, service.demo_keys
    assert keys is not None
    req = keys.address("user1")
    cid = "bafkreihdwdcefgh4dqkjv67uzcmw7ojee6xedzdetojuzjevtenxquvyku"
    with service.lock:
        p.umc.add_requester(req)
        first, _ = p.tmc.add_task(req, domain=0, num_workers=1, reward=10**12, duration=3_600,
                                  description=cid)
    send(service, req, p.tmc.address, add_task_calldata(NOT_UTF8), value=10**12)
    assert task_spec_cid(p, first) == cid
    assert task_spec_cid(p, first + 1) == NOT_UTF8.decode(errors="replace")


def test_a_huge_description_written_straight_to_the_chain_is_cut_in_the_index(
    service: ChainService, any_sessions: sessionmaker[Session]
) -> None:
    """The contracts took a description of any length (only gas bounded it): one of 50,000
    characters was kept whole in ``chain_events.args``, so every timeline page of that task
    carried it. The chain now caps it at ``MAX_DESCRIPTION_BYTES``, which still holds more
    characters than the index keeps: the index keeps ``EVENT_TEXT_LIMIT`` characters and says
    how many it cut; the task row keeps its own column's width."""
    from backend.indexer.indexer import EVENT_TEXT_LIMIT

    p, keys = service.platform, service.demo_keys
    assert keys is not None
    req = keys.address("user1")
    with service.lock:
        p.umc.add_requester(req)
    cap = p.tmc.call("MAX_DESCRIPTION_BYTES")
    accents = 600  # 2 bytes each in UTF-8
    huge = ("\u00e9" * accents + "x" * (cap - 2 * accents)).encode()  # the cap, in bytes
    characters = cap - accents
    assert len(huge) == cap and characters > EVENT_TEXT_LIMIT + accents
    send(service, req, p.tmc.address, add_task_calldata(huge), value=10**12)
    Indexer(service, any_sessions).poll()

    with any_sessions() as s:
        args: Any = s.scalars(select(m.ChainEvent.args)
                              .where(m.ChainEvent.name == "TaskAdded")).one()
        row = s.scalars(select(m.TaskRow)).one()
    kept = args["description"]
    assert kept.startswith("\u00e9" * accents + "x" * (EVENT_TEXT_LIMIT - accents) + "\u2026")
    assert kept.endswith(f"[{characters - EVENT_TEXT_LIMIT} more characters on chain]")
    assert len(kept) < EVENT_TEXT_LIMIT + 64
    assert row.description == "\u00e9" * 512
    assert args["taskId"] == row.id  # the event's other args are as they were
