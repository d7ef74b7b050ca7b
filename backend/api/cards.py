"""Model cards read from the content store: a listed model's (``GET /models/{id}``) and a task's
outcomes' (``GET /tasks/{id}``: the worker's trial of each expert, the evidence for the
requester's review, whether or not the outcome was ever shared, sealed or not: a sealed
bundle's card is plain text).

A card is anyone's file: it is bounded in size and depth, and only what validates is shown
(``backend.schemas.cards.CardView``). A CID names its content for good, so the parsed card of
an outcome is kept (:class:`OutcomeCards`, ``app.state.outcome_cards``, at most
:data:`KEPT_CARDS`); a card the
store cannot give now is asked for again after :data:`RETRY_S`, not on every poll of the task
page (the UI polls every 2 s, and a real node may take its find timeout to say "not found").
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from backend.api.limits import json_depth_exceeds
from backend.schemas.cards import CardView, ExpertTrialPublic
from backend.store import ContentStore, StoreError
from backend.store.bundle import MAX_CARD_BYTES, bundle_entry

log = logging.getLogger(__name__)

MAX_CARD_DEPTH = 32
KEPT_CARDS = 512
"""Outcome cards kept parsed per gateway (a few hundred bytes each once parsed)."""
RETRY_S = 60.0
"""Seconds before a card the store did not give is asked for again."""


def read_card(store: ContentStore, cid: str) -> dict[str, Any] | None:
    """The bundle's card, or None when it is missing, too large, too deep or not a JSON object
    (it is anyone's file: the answer must serialise whatever it holds; NaN/Infinity, which
    Python's parser accepts and JSON does not, become null)."""
    try:
        card_cid, size = bundle_entry(store, cid, "model.json")
        if size > MAX_CARD_BYTES:
            return None
        raw = store.get(card_cid, max_size=MAX_CARD_BYTES)
        if json_depth_exceeds(raw, MAX_CARD_DEPTH):
            raise ValueError(f"nested deeper than {MAX_CARD_DEPTH} levels")
        card = json.loads(raw, parse_constant=lambda _: None)
        return card if isinstance(card, dict) else None
    except (KeyError, ValueError, RecursionError, StoreError) as exc:
        log.info("model card of %s unavailable: %s", cid, exc)
        return None


class OutcomeCards:
    """The validated cards of outcomes by CID, kept (content-addressed: they never change);
    a miss is retried after ``retry_s``."""

    def __init__(self, kept: int = KEPT_CARDS, retry_s: float = RETRY_S,
                 clock: Callable[[], float] = time.monotonic):
        self.kept, self.retry_s, self.clock = kept, retry_s, clock
        self._views: OrderedDict[str, CardView] = OrderedDict()
        self._missed: dict[str, float] = {}  # cid -> when to ask again
        self._lock = threading.Lock()

    def view(self, store: ContentStore, cid: str, read: bool = True) -> CardView | None:
        """The card of ``cid`` as validated; None when ``store`` does not give it (or, with
        ``read`` False, when it is not kept already)."""
        with self._lock:
            if cid in self._views:
                self._views.move_to_end(cid)
                return self._views[cid]
            if not read or self._missed.get(cid, 0.0) > self.clock():
                return None
        card = read_card(store, cid)  # outside the lock: a slow store stalls no other cid
        with self._lock:
            if card is None:
                self._missed[cid] = self.clock() + self.retry_s
                if len(self._missed) > self.kept:  # forget the oldest misses
                    for old in list(self._missed)[: len(self._missed) - self.kept]:
                        del self._missed[old]
                return None
            self._missed.pop(cid, None)
            view = self._views[cid] = CardView.from_card(card)
            while len(self._views) > self.kept:
                self._views.popitem(last=False)
            return view


def expert_trials(
    cards: OutcomeCards, store: ContentStore, outcomes: list[tuple[str, str]], read: bool = True
) -> dict[str, list[tuple[str, ExpertTrialPublic]]]:
    """{expert ref: [(worker, its trial in that worker's outcome card)]} over ``outcomes``
    ((worker, outcome CID)): ``training.experts.review`` of each card, as validated; with
    ``read`` False only from the cards kept already."""
    out: dict[str, list[tuple[str, ExpertTrialPublic]]] = {}
    for worker, cid in outcomes:
        view = cards.view(store, cid, read)
        if view is None:
            continue
        for ref, usage in view.expert_usage.items():
            if usage.trial is not None:
                out.setdefault(ref, []).append((worker, usage.trial))
    return out
