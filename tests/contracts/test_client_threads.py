"""One signing key, two threads: ``Chain`` takes the nonce and sends as one step, so the
worker daemon's background recovery (which may give a failed job back) never makes the job
it runs meanwhile send a transaction with a nonce already used."""

from __future__ import annotations

import threading


def test_one_key_sending_from_two_threads_never_reuses_a_nonce(p, actors) -> None:
    failures: list[BaseException] = []
    start = p.chain.w3.eth.block_number + 1
    barrier = threading.Barrier(2)

    def send(first_limit: int) -> None:
        try:
            barrier.wait(timeout=30)
            for k in range(8):
                p.mmc.transact("setMaxModelsPerOwner", first_limit + k, sender=actors.admin)
        except BaseException as exc:  # noqa: BLE001 - reported below
            failures.append(exc)

    threads = [threading.Thread(target=send, args=(start,)) for start in (1, 9)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert failures == []
    updates = p.mmc.contract.events.MaxModelsPerOwnerUpdated().get_logs(from_block=start)
    assert sorted(e.args["limit"] for e in updates) == list(range(1, 17))
