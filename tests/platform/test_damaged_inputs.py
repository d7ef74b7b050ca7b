"""The worker daemon against damaged or hostile input (the probe of 2026-11-28, evening):
numbers JSON allows but floats do not hold, JSON nested past the parser's depth, state.json
files that are valid JSON of the wrong shape, and a give-back that meets an outcome mined
after all. Each is declined, recovered or recorded with a reason, never an exception out of
the handler."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from web3.exceptions import TimeExhausted

from backend.chain.platform import OfferState
from backend.store.bundle import add_bundle
from workers.daemon.handler import Transient
from workers.mdrl.trainingspec import TrainingSpec

from .helpers import TINY_SPEC, post_task
from .test_handler import handler_for

EXPERT = Path(__file__).resolve().parents[2] / "models" / "odmtl-2a"
HUGE = 10**400  # a JSON integer float() cannot hold (OverflowError)
NESTED = b"[" * 30_000 + b"]" * 30_000  # deeper than json's recursion, under 64 KiB


def _post_raw(p, store, requester: str, raw: bytes) -> tuple[int, list[str]]:
    task_id, _ = p.tmc.add_task(requester, domain=0, num_workers=1, reward=10**15,
                                duration=3600, description=store.add(raw))
    offered, _ = p.tmc.allocate(requester, task_id)
    return task_id, offered


def _expert(store, **changes: bytes) -> str:
    files = {n: (EXPERT / n).read_bytes() for n in ("model.safetensors", "model.json")}
    return add_bundle(store, {**files, **changes})


def _medc(cid: str) -> dict:
    return {**TINY_SPEC, "experts": [cid], "algorithm": {"demonstration": {"rate": 0.5}}}


@pytest.mark.parametrize("field, spec", [
    ("budget.minutes", {**TINY_SPEC, "budget": {"minutes": HUGE}}),
    ("env.intensity", {**TINY_SPEC, "env": {**TINY_SPEC["env"], "intensity": HUGE}}),
])
def test_a_number_too_large_for_a_float_is_declined_naming_its_field(
    env, tmp_path: Path, field: str, spec: dict  # noqa: F811
) -> None:
    p, actors, store = env
    task_id, offered = _post_raw(p, store, actors.requester, json.dumps(spec).encode())
    out = handler_for(p, offered[0], store, tmp_path).handle(task_id, offered[0])
    assert out["status"] == "declined" and field in out["reason"], out
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED


def test_experts_with_a_huge_number_or_a_nested_manifest_are_declined_naming_them(
    env, tmp_path: Path  # noqa: F811
) -> None:
    p, actors, store = env
    card = json.loads((EXPERT / "model.json").read_text())
    card["env"]["intensity"] = HUGE
    for cid in (_expert(store, **{"model.json": json.dumps(card).encode()}), store.add(NESTED)):
        task_id, offered, _ = post_task(p, store, actors.requester, spec=_medc(cid))
        out = handler_for(p, offered[0], store, tmp_path).handle(task_id, offered[0])
        assert out["status"] == "declined" and cid in out["reason"], out


def test_a_state_set_aside_while_the_node_is_down_is_recovered_when_it_is_back(
    env, tmp_path: Path  # noqa: F811
) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    p.tmc.transact("acceptOffer", task_id, sender=worker)
    h = handler_for(p, worker, store, tmp_path)
    h._save(task_id, phase="trained")
    (h.job_dir(task_id) / "state.json").write_text("{")  # a disk fault
    settle = h._settle

    def node_down(tid: int, st: dict) -> None:
        raise Transient("chain node unreachable during reading the offer: refused")

    h._settle = node_down  # type: ignore[method-assign]
    assert h.recover(lambda tid, w: None)["deferred"] == [task_id]
    h._settle = settle  # type: ignore[method-assign]  # the node is back
    queued: list[int] = []
    assert h.recover(lambda tid, w: queued.append(tid), only={task_id})["queued"] == [task_id]
    assert queued == [task_id] and h.active_jobs(exclude=0) == [task_id]
    assert list(h.job_dir(task_id).glob("state.json.unreadable-*"))


def test_a_state_nested_past_the_parser_or_of_an_unknown_phase_is_rebuilt_from_the_chain(
    env, tmp_path: Path  # noqa: F811
) -> None:
    p, actors, store = env
    t_nested, offered, _ = post_task(p, store, actors.requester, num_workers=3)
    worker = offered[0]
    t_typo, o2, _ = post_task(p, store, actors.requester, num_workers=3)
    assert worker in o2
    h = handler_for(p, worker, store, tmp_path)
    for tid in (t_nested, t_typo):
        p.tmc.transact("acceptOffer", tid, sender=worker)
    h._save(t_nested, phase="accepted")
    (h.job_dir(t_nested) / "state.json").write_bytes(NESTED)
    h._save(t_typo, phase="traning")  # not a phase the daemon writes
    queued: list[int] = []
    done = h.recover(lambda tid, w: queued.append(tid))
    assert done["queued"] == [t_nested, t_typo] and queued == [t_nested, t_typo], done
    assert h._state(t_nested)["phase"] == h._state(t_typo)["phase"] == "accepted"
    assert sorted(h.active_jobs(exclude=0)) == [t_nested, t_typo]


@pytest.mark.parametrize("bad", [
    {"starts_without_progress": None},
    {"starts_without_progress": True, "resumed_from_step": "0"},
])
def test_counters_of_the_wrong_type_in_state_json_do_not_fail_the_job(
    env, tmp_path: Path, bad: dict  # noqa: F811
) -> None:
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    p.tmc.transact("acceptOffer", task_id, sender=worker)
    h = handler_for(p, worker, store, tmp_path)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    h._save(task_id, phase="accepted", **bad)
    assert h.handle(task_id, worker)["status"] == "submitted"


def test_giving_up_on_a_submit_that_was_mined_after_all_records_it_submitted(
    env, tmp_path: Path, monkeypatch  # noqa: F811
) -> None:
    """The last retry's submitOutcome is mined but its receipt wait gives up; give_up's
    abandonOffer is refused (the offer is Submitted): the job is recorded as submitted, so
    ``drlaas worker share`` can publish it."""
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester)
    worker = offered[0]
    h = handler_for(p, worker, store, tmp_path)
    h._post_progress = lambda tid, point: None  # type: ignore[method-assign]
    real = p.tmc.transact

    def late(fn, *args, **kw):
        if fn == "submitOutcome":
            real(fn, *args, **kw)
            raise TimeExhausted("not in the chain after 120 seconds")
        return real(fn, *args, **kw)

    monkeypatch.setattr(p.tmc, "transact", late)
    with pytest.raises(Transient):
        h.handle(task_id, worker)
    out = h.give_up(task_id, "gave up after 8 retries: chain node unreachable")
    monkeypatch.undo()
    assert out["status"] == "submitted" and h._state(task_id)["phase"] == "submitted"
    p.tmc.transact("reviewOutcome", task_id, worker, 4, True, sender=actors.requester)
    assert h.publish_outcome(task_id)["cid"] == out["cid"]


def test_an_offer_whose_deadline_leaves_less_than_one_update_is_declined(
    env, tmp_path: Path  # noqa: F811
) -> None:
    """A time budget is checked between updates: a spec whose single update (here 120,000
    env steps, 30 epochs: about a minute by the resource model) does not fit before the
    deadline is declined, naming both times, instead of trained past the deadline."""
    import time

    from workers.daemon.handler import DEADLINE_MARGIN_S

    slow = {**TINY_SPEC, "budget": {"steps": 120_000},
            "algorithm": {"ppo": {"num_envs": 8, "horizon": 120_000, "update_epochs": 30}}}
    p, actors, store = env
    task_id, offered, _ = post_task(p, store, actors.requester, spec=slow)
    h = handler_for(p, offered[0], store, tmp_path)
    deadline = int(p.tmc.task(task_id)["deadline"])
    h.clock = lambda: deadline - DEADLINE_MARGIN_S - 5.0  # 5 s to train before the margin
    out = h.handle(task_id, offered[0])
    assert out["status"] == "declined" and out["reason"].startswith("deadline: one PPO update")
    assert "leaves 5 s" in out["reason"], out
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED
    h.clock = time.time  # the whole window ahead: the same offer would be taken
    assert h._cannot_take(task_id, TrainingSpec.from_dict(slow), actors.requester,
                          deadline=deadline) is None
