"""Hostile tasks and models against the worker daemon (the probe of 2026-12-04): what a
requester can put in the content store (a spec, expert bundles), bypassing the gateway's
checks. Each is refused on what it says or bounded in what it costs, never a worker
exhausting its memory or CPU, nor a task lost past its deadline."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest
import torch
from safetensors.torch import load, save

from backend.chain.platform import OfferState
from backend.store import CID
from backend.store.bundle import add_bundle
from workers.daemon import job as jobs
from workers.daemon.experts import expert_key
from workers.mdrl.trainingspec import TrainingSpec

from .helpers import TINY_SPEC, post_task
from .test_handler import handler_for

torch.set_num_threads(1)

MODELS = Path(__file__).resolve().parents[2] / "models"
EXPERT = MODELS / "odmtl-2a"  # 10x10, 2 agents, window 5


def _bundle(weights: dict[str, torch.Tensor], card: dict) -> dict[str, bytes]:
    return {"model.safetensors": save(weights), "model.json": json.dumps(card).encode()}


def _walls_encoder_expert(channels: int) -> dict[str, bytes]:
    """The 10x10 expert, its card claiming a walls encoder of ``channels`` conv layers (the
    weights carry one ``walls_encoder.*`` tensor, as a model with an encoder does)."""
    card = json.loads((EXPERT / "model.json").read_text())
    card["observation"] |= {"walls_embedding": "bafyanyencoder", "walls_embedding_size": 4}
    card["walls_encoder"] = {"kind": "cae", "grid": [10, 10], "embedding": 4,
                             "channels": [1] * channels, "digest": "sha256:0"}
    weights = load((EXPERT / "model.safetensors").read_bytes())
    return _bundle(weights | {"walls_encoder.fc.weight": torch.zeros(1, 1)}, card)


def test_an_expert_card_claiming_a_huge_walls_encoder_is_declined_on_its_card(
    env, tmp_path: Path
) -> None:
    """A card's ``walls_encoder.channels`` is one conv layer per entry: a 1 MiB card lists
    ~500,000, and the worker built them all (~100 s of CPU and GBs of memory, before it found
    the weights do not match) while checking the offer. Bounded as a walls CAE's card is
    (``cae.check_cae_fields``), the offer is declined on the card alone, weights unfetched."""
    p, actors, store = env
    cid = add_bundle(store, _walls_encoder_expert(channels=2000))
    spec = {**TINY_SPEC, "env": {"rows": 10, "cols": 10, "agents": 2}, "experts": [cid]}
    task_id, offered, _ = post_task(p, store, actors.requester, spec=spec)
    h = handler_for(p, offered[0], store, tmp_path)
    out = h.handle(task_id, offered[0])
    assert out["status"] == "declined" and f"expert {cid}" in out["reason"], out
    assert "walls_encoder" in out["reason"] and "out of range" in out["reason"], out["reason"]
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED
    assert h.cache.get(cid) is None  # refused on its card: the weights were never fetched
    assert not (h.job_dir(task_id) / "experts" / expert_key(cid)).exists()


def test_the_experts_trial_cannot_run_past_the_deadline(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """After training, the worker runs each expert followed by the team for 100 episodes of up
    to ``max_steps`` (10,000 allowed) each: with an expert that never finds the source (here
    zeroed weights) and a large task that is hours, while only TRIAL_TIME_S (60 s) was kept
    for it. The job then ran past its deadline and its trained model was never submitted. The
    trial now gets the time left before the deadline's margin, and the model is delivered
    without it when that is not enough."""
    expert = tmp_path / "dumb"
    expert.mkdir()
    weights = load((MODELS / "odmtl-1a" / "model.safetensors").read_bytes())
    (expert / "model.safetensors").write_bytes(save({k: torch.zeros_like(v)
                                                     for k, v in weights.items()}))
    (expert / "model.json").write_bytes((MODELS / "odmtl-1a" / "model.json").read_bytes())
    spec = TrainingSpec.from_dict({
        "env": {"rows": 12, "cols": 12, "agents": 1, "max_steps": 8000},
        "observation": {"kind": "odmtl", "window": 3},
        "budget": {"steps": 256}, "seed": 1, "experts": ["bafyexpert"],
        "algorithm": {"ppo": {"num_envs": 8, "horizon": 16, "update_epochs": 1}},
    })
    # the job hands the trial the time it has left
    given: list[float | None] = []
    monkeypatch.setattr(jobs, "attach_expert_review",
                        lambda model, spec, experts, *, seconds=None: given.append(seconds))
    monkeypatch.setattr(jobs, "TRIAL_TIME_S", 1.0)
    left_s = 120.0
    jobs.run_job(spec, tmp_path / "job", minutes_left=left_s / 60, checkpoint_every=0,
                 experts={"bafyexpert": expert})
    assert len(given) == 1 and given[0] is not None and 1.0 <= given[0] < left_s
    monkeypatch.undo()
    # ... which cuts it (unbounded, ~13 s here), and the model goes without it
    model = tmp_path / "job" / "run" / "model"
    with caplog.at_level(logging.WARNING, logger=jobs.log.name):
        jobs.attach_expert_review(model, spec, {"bafyexpert": expert}, seconds=0.5)
    card = json.loads((model / "model.json").read_text())
    assert "review" not in card["training"]["experts"]
    assert "TrialTimeout" in caplog.text
    assert (tmp_path / "job" / jobs.FINISHED_MARK).is_file()


def test_one_expert_named_twice_by_its_two_cid_versions_is_declined(
    env, tmp_path: Path
) -> None:
    """The spec's duplicate check compares text; a spec written straight to the store (the
    gateway takes canonical CIDs only) can name one bundle in two spellings (base32 in lower
    and upper case): the worker would train with it as two experts and the card list it
    twice. It declines instead."""
    p, actors, store = env
    cid = add_bundle(store, _bundle(load((EXPERT / "model.safetensors").read_bytes()),
                                    json.loads((EXPERT / "model.json").read_text())))
    alias = cid.upper()
    assert alias != cid and CID.parse(alias) == CID.parse(cid)
    spec = {**TINY_SPEC, "env": {"rows": 10, "cols": 10, "agents": 2}, "experts": [cid, alias]}
    task_id, offered, _ = post_task(p, store, actors.requester, spec=spec)
    out = handler_for(p, offered[0], store, tmp_path).handle(task_id, offered[0])
    assert out["status"] == "declined" and "the same model twice" in out["reason"], out
    assert p.tmc.offer(task_id, offered[0])["state"] == OfferState.DECLINED
