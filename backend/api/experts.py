"""The experts of a training task (MEDC, thesis Alg. 5.1 and the model-sharing flow of 7.8):
checked when the task is created, and shown with the task.

A requester names expert models by CID in the spec (``experts``), or names one of its MMC
allocations (``expert_allocation``: the paid model-sharing task of Eq. 10-13 / 22-23) and the
gateway writes the allocated models' CIDs with the QoS the MMC computed for them (the
``ModelAllocated`` events) into the spec: R_S = QoS_i / sum QoS is then each expert's chance to
guide an episode (Table 5.3). Every expert must be a canonical CID whose bundle the content
store holds and which passes the gateway's check of a model bundle
(``backend.api.bundles.check_model_bundle``: exactly the two files, a ``drlaas-model/1`` card,
safetensors weights within bounds): the workers fetch and verify it again
(``workers.daemon.experts``), this refuses before the task is created (and paid for) what no
worker could use.
"""

from __future__ import annotations

import math
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from backend.api.bundles import BundleRefused, check_model_bundle
from backend.api.errors import RuleError
from backend.api.writes import field_error
from backend.db import models as m
from backend.schemas.common import from_fixed
from backend.store import CID, ContentStore, InvalidCID, NotFound, StoreError, StoreUnavailable
from workers.mdrl.cae import check_cae_fields
from workers.mdrl.experts import expert_misfit
from workers.mdrl.modelio import card_specs
from workers.mdrl.trainingspec import MAX_EXPERTS

CAE_KIND = "cae"
"""``kind`` of a walls CAE's card (``workers.mdrl.cae``); a policy's card has none."""


def allocation_experts(session: Session, alloc_id: int, caller: str) -> list[Any]:
    """The ``experts`` of a spec from the caller's allocation ``alloc_id``: ``{model, qos}``
    per allocated model (QoS as the MMC emitted it), or plain CIDs when every QoS is 0."""
    alloc = session.get(m.AllocationRow, alloc_id)
    loc = ("body", "expert_allocation")
    if alloc is None:
        field_error(
            loc, f"no model allocation {alloc_id} (or not indexed yet)", "allocation_not_found"
        )
    if alloc.requester != caller:
        raise RuleError(
            403,
            "not_allocation_requester",
            f"allocation {alloc_id} belongs to {alloc.requester}, not {caller}",
        )
    rows = session.execute(
        select(m.AllocatedModel.qos, m.ModelRow.cid)
        .join(m.ModelRow, m.ModelRow.id == m.AllocatedModel.model_id)
        .where(m.AllocatedModel.alloc_id == alloc_id)
        .order_by(m.AllocatedModel.qos.desc(), m.AllocatedModel.model_id)
    ).all()
    if not rows:
        field_error(loc, f"allocation {alloc_id} holds no model", "allocation_empty")
    if len(rows) > MAX_EXPERTS:
        field_error(
            loc,
            f"allocation {alloc_id} holds {len(rows)} models; a task trains with at most "
            f"{MAX_EXPERTS} experts: name the ones to use in experts instead",
            "allocation_too_many_experts",
        )
    if not any(q for q, _ in rows):
        return [cid for _, cid in rows]
    return [{"model": cid, "qos": from_fixed(q)} for q, cid in rows]


def check_experts(store: ContentStore, refs: tuple[str, ...]) -> list[dict[str, Any]]:
    """422 naming ``experts[i]`` unless each is a canonical CID of a model bundle in the store
    that passes ``check_model_bundle`` (its two files, a ``drlaas-model/1`` card, safetensors
    weights); 503 while the store is down. Returns their cards, in order."""
    return [
        _check_model(store, ref, ("body", "experts", i), "expert") for i, ref in enumerate(refs)
    ]


def expert_specs(spec: Any, cards: list[dict[str, Any]]) -> list[tuple[Any, Any]]:
    """The (EnvSpec, ObservationSpec) of each expert a run of ``spec`` loads (QoS > 0), from
    their ``cards`` (:func:`check_experts`), for the resource estimate; 422 naming
    ``experts[i]`` for a card that does not describe them (``expert_invalid``) or an expert
    that cannot serve the task's env (``expert_misfit``: the check a worker runs before it
    accepts, so such a task would only collect declines)."""
    demo = spec.demonstration()
    loaded = set(demo.experts) if demo is not None else set()
    out = []
    for i, (ref, card) in enumerate(zip(spec.experts, cards, strict=True)):
        if ref not in loaded:
            continue
        loc = ("body", "experts", i)
        try:
            env, obs = card_specs(card)
        except (ValueError, TypeError, KeyError) as exc:  # SpecError is a ValueError
            field_error(loc, f"{ref} is not a usable model: {exc}", "expert_invalid")
        why = expert_misfit(env, obs.kind, bool(obs.walls_embedding), spec.env)
        if why is not None:
            field_error(loc, f"{ref} cannot serve this task: {why}", "expert_misfit")
        out.append((env, obs))
    return out


def check_walls_cae(
    store: ContentStore, ref: str | None, grid: tuple[int, int], size: int
) -> dict[str, Any] | None:
    """The same for a spec's walls CAE (``observation.walls_embedding``, Ch. 4), whose card
    must be a CAE's (kind ``cae``) for this grid with embedding size ``size``
    (``observation.walls_embedding_size``): a worker could not use any other, so the job would
    fail only after it was paid for. Codes ``walls_cae_*``. Returns the card (None: no CAE)."""
    if ref is None:
        return None
    loc = ("body", "observation", "walls_embedding")
    card = _check_model(store, ref, loc, "walls_cae")
    try:  # what a worker rebuilds (and the resource estimate sizes) the encoder from
        check_cae_fields(card)
    except ValueError as exc:
        field_error(loc, f"{ref} is not a usable walls CAE: {exc}", "walls_cae_invalid")
    cae_grid = card.get("grid")
    if cae_grid != list(grid):
        field_error(
            loc,
            f"this walls CAE was trained for a {_grid(cae_grid)} grid, "
            f"the task's is {grid[0]} x {grid[1]}",
            "walls_cae_grid_mismatch",
        )
    if card.get("embedding") != size:
        field_error(
            ("body", "observation", "walls_embedding_size"),
            f"the walls CAE embeds in d = {card.get('embedding')!r}, "
            f"the spec says walls_embedding_size = {size}",
            "walls_cae_size_mismatch",
        )
    return card


def _grid(g: Any) -> str:
    return f"{g[0]} x {g[1]}" if isinstance(g, list) and len(g) == 2 else repr(g)


def _check_model(store: ContentStore, ref: str, loc: tuple[Any, ...], what: str) -> dict[str, Any]:
    """The bundle's card once ``ref`` passes (else a 422 / 503, see callers)."""
    try:
        canonical = str(CID.parse(ref).v1())
    except (InvalidCID, ValueError):
        field_error(
            loc,
            f"{ref!r} is not a model CID: a platform task names its models by "
            f"the CID of their bundle (no paths, no built-ins)",
            f"{what}_not_cid",
        )
    if canonical != ref:
        field_error(
            loc,
            f"give the CID in the store's canonical form: {canonical}",
            f"{what}_not_canonical",
        )
    try:
        card = check_model_bundle(store, ref).card
        is_cae = card.get("kind") == CAE_KIND
        if is_cae != (what == "walls_cae"):
            raise ValueError(
                "its card is a walls CAE's, not a policy's"
                if is_cae
                else "its card is a policy's, not a walls CAE's"
            )
        return card
    except BundleRefused as exc:
        # the bundle's files missing from the store: as the bundle itself, else unusable
        missing = exc.rule == "bundle_file_not_found"
        field_error(
            loc,
            f"{ref} is not a usable model: {exc.msg} ({exc.rule})",
            f"{what}_not_found" if missing else f"{what}_invalid",
        )
    except NotFound:
        field_error(loc, f"the content store does not hold {ref}", f"{what}_not_found")
    except StoreUnavailable as exc:
        raise RuleError(
            503, "store_unavailable", f"content store: {exc}", headers={"Retry-After": "5"}
        ) from None
    except (ValueError, RecursionError, StoreError) as exc:
        field_error(loc, f"{ref} is not a usable model: {exc}", f"{what}_invalid")


def task_experts(
    session: Session, spec: dict[str, Any] | None, requester: str
) -> list[dict[str, Any]]:
    """The experts a task's spec names, each with its QoS weight, its MMC model (id,
    reputation) when listed, and the requester's latest allocation of that model (id and
    review, for ``updateModelRep``)."""
    items = (spec or {}).get("experts") or []
    if not isinstance(items, list):  # an index row from before specs were validated
        return []
    weighted = any(isinstance(x, dict) for x in items)
    out = []
    for x in items[:64]:
        cid = x.get("model") if isinstance(x, dict) else x
        if not isinstance(cid, str):
            continue
        qos = x.get("qos", 1.0) if isinstance(x, dict) else 1.0
        if isinstance(qos, bool) or not isinstance(qos, (int, float)) or not math.isfinite(qos):
            continue
        qos = float(qos)
        model = session.scalars(select(m.ModelRow).where(m.ModelRow.cid == cid)).first()
        alloc = None
        if model is not None:
            alloc = session.execute(
                select(m.AllocatedModel.alloc_id, m.AllocatedModel.review)
                .join(m.AllocationRow, m.AllocationRow.id == m.AllocatedModel.alloc_id)
                .where(
                    m.AllocatedModel.model_id == model.id, m.AllocationRow.requester == requester
                )
                .order_by(m.AllocatedModel.alloc_id.desc())
            ).first()
        out.append(
            {
                "cid": cid,
                "qos": qos if weighted else None,
                "model_id": model.id if model else None,
                "reputation": from_fixed(model.reputation) if model else None,
                "alloc_id": alloc.alloc_id if alloc else None,
                "review": alloc.review if alloc else None,
            }
        )
    return out
