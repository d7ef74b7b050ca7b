"""Outcome cards read for the task page (backend/api/cards.py): a card is read from the store
once per CID and kept; a card the store does not give is asked for again only after RETRY_S;
what does not validate (a suggestion out of 0-5) is not shown."""

from __future__ import annotations

import json

from backend.api.cards import OutcomeCards, expert_trials
from backend.store import EmbeddedStore
from backend.store.bundle import add_bundle

EXPERT = "bafkreigh2akiscaildcqabsyg3dfr6chu3fgpregiymsck7e7aqa4s52zy"
OTHER = "bafkreihdwdcefgh4dqkjv67uzcmw7ojee6xedzdetojuzjevtenxquvyku"


def outcome(store: EmbeddedStore, suggested: int, time: float = 12.0) -> str:
    card = {"format": "drlaas-model/1", "training": {"experts": {
        "experts": [{"ref": EXPERT, "episodes": 3, "decisions": 30, "followed": 30},
                    {"ref": OTHER, "episodes": 3, "decisions": 30, "followed": 30}],
        "review": {"episodes": 100, "experts": [
            {"ref": EXPERT, "success": 1.0, "time": time, "time_vs_oracle": 1.25,
             "suggested_review": suggested},
            {"ref": OTHER, "success": 1.0, "time": 9.0, "suggested_review": 9}]}}}}
    return add_bundle(store, {"model.safetensors": b"w", "model.json": json.dumps(card).encode()})


class CountingStore(EmbeddedStore):
    def __init__(self, root):
        super().__init__(root)
        self.gets = 0

    def get(self, cid, *args, **kwargs):
        self.gets += 1
        return super().get(cid, *args, **kwargs)


def test_trials_by_expert_and_worker_with_what_does_not_validate_left_out(tmp_path) -> None:
    store = EmbeddedStore(tmp_path)
    a, b = outcome(store, 4), outcome(store, 2, time=20.0)
    trials = expert_trials(OutcomeCards(), store, [("0xA", a), ("0xB", b)])
    assert list(trials) == [EXPERT]  # OTHER's suggestion of 9/5 does not validate
    assert [(w, t.suggested_review, t.time, t.episodes) for w, t in trials[EXPERT]] == [
        ("0xA", 4, 12.0, 100), ("0xB", 2, 20.0, 100)]


def test_a_card_is_read_once_and_a_miss_is_retried_after_a_while(tmp_path) -> None:
    store = CountingStore(tmp_path)
    now = [0.0]
    cards = OutcomeCards(kept=2, retry_s=60.0, clock=lambda: now[0])
    cid = outcome(store, 4)
    assert cards.view(store, cid) is not None
    reads = store.gets
    for _ in range(5):  # the task page polls: the card comes from memory
        assert cards.view(store, cid).expert_usage[EXPERT].trial.suggested_review == 4
    assert store.gets == reads

    missing = "bafkreibm6jg3ux5qumhcn2b3flc3tyu6dmlb4xa7u5bf44yegnrjhc4yeq"
    assert cards.view(store, missing) is None
    reads = store.gets
    now[0] = 59.0
    assert cards.view(store, missing) is None and store.gets == reads  # not asked again yet
    now[0] = 61.0
    assert cards.view(store, missing) is None and store.gets > reads  # asked again

    more = [outcome(store, s) for s in (1, 2)]  # at most `kept` cards stay
    for c in more:
        cards.view(store, c)
    reads = store.gets
    cards.view(store, cid)  # pushed out by the two newer ones: read again
    assert store.gets > reads


def test_without_a_store_read_only_the_kept_cards_answer(tmp_path) -> None:
    """The task page takes a store-read slot to read a card; when none is free it answers
    from the cards kept already (read=False), without touching the store."""
    store = CountingStore(tmp_path)
    kept, new = outcome(store, 4), outcome(store, 2)
    cards = OutcomeCards()
    cards.view(store, kept)
    reads = store.gets
    assert cards.view(store, new, read=False) is None
    assert cards.view(store, kept, read=False) is not None
    assert store.gets == reads
    assert cards.view(store, new) is not None  # not remembered as a miss: read when a slot is free
