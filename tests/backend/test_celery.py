"""A real Celery worker process executes a task through each broker kind.

The embedded broker runs everywhere; Redis and RabbitMQ are exercised when they listen on
loopback (this project's machines) and skipped with the reason otherwise.
"""

from __future__ import annotations

import os
import signal
import statistics
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from celery import Celery

from backend.celery_app import (
    EMBEDDED_POLLING_INTERVAL_S,
    broker_config,
    make_celery,
    worker_queue,
)
from backend.settings import Settings, load_settings

from .conftest import port_open

REPO = Path(__file__).resolve().parents[2]
CELERY = Path(sys.executable).with_name("celery")


def start_worker(
    settings_env: dict[str, str], queue: str, log: Path, app: str = "backend.celery_app"
) -> subprocess.Popen:
    env = {k: v for k, v in os.environ.items() if not k.startswith("DRLAAS_")}
    env.update(settings_env, PYTHONPATH=str(REPO))
    cmd = [
        str(CELERY),
        "-A",
        app,
        "worker",
        "--pool",
        "solo",
        "-Q",
        queue,
        "-n",
        f"test-{uuid.uuid4().hex[:8]}@%h",
        "--without-heartbeat",
        "--without-gossip",
        "--without-mingle",
        "--loglevel",
        "INFO",
    ]
    return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=log.open("wb"), stderr=subprocess.STDOUT)


def stop_worker(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)  # warm shutdown
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


def round_trips(app: Celery, queue: str, n: int, log: Path) -> list[float]:
    """Seconds per ping round trip; the first call waits for the worker to come up."""
    first = app.send_task("drlaas.ping", args=["warm-up"], queue=queue)
    try:
        reply = first.get(timeout=60, interval=0.02)
    except Exception as exc:  # show the worker's log: it says why
        raise AssertionError(f"worker never answered ({exc!r}); log:\n{log.read_text()}") from exc
    assert reply["pong"] == "warm-up"
    assert reply["pid"] != os.getpid()  # answered by the worker process, not in-process
    times = []
    for i in range(n):
        t0 = time.perf_counter()
        token = f"t{i}-{uuid.uuid4().hex}"
        reply = app.send_task("drlaas.ping", args=[token], queue=queue).get(
            timeout=30, interval=0.02
        )
        times.append(time.perf_counter() - t0)
        assert reply["pong"] == token
    return times


@pytest.fixture
def run_worker(tmp_path: Path) -> Iterator:
    procs: list[subprocess.Popen] = []

    def run(
        env: dict[str, str], queue: str, app: str = "backend.celery_app"
    ) -> tuple[Celery, Path, subprocess.Popen]:
        env = {"DRLAAS_DATA_DIR": str(tmp_path / "data"), **env}
        settings = load_settings(**{k.removeprefix("DRLAAS_").lower(): v for k, v in env.items()})
        log = tmp_path / f"worker-{len(procs)}.log"
        procs.append(start_worker(env, queue, log, app))
        return make_celery(settings), log, procs[-1]

    yield run
    for p in procs:
        stop_worker(p)


def test_embedded_broker_round_trip_is_fast(run_worker) -> None:
    """No server at all; polling at 50 ms instead of kombu's 1 s default (which measured
    ~1.03 s per sequential round trip here)."""
    app, log, _ = run_worker({}, "q")
    times = round_trips(app, "q", 7, log)
    assert statistics.median(times) < 0.5, times


def wait_for(predicate, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.05)


def test_embedded_broker_redelivers_a_job_whose_worker_was_killed(
    run_worker, tmp_path: Path
) -> None:
    """acks_late on the embedded broker: kill -9 mid-job, the next worker on the queue runs it
    again; a finished job is never run twice."""
    queue = worker_queue("0x7e5f4552091a69125d5dfcb7b8c2659029395bdf")
    trace = tmp_path / "trace.txt"
    trace.touch()
    jobs = "tests.backend.celery_jobs"
    app, log_a, worker_a = run_worker({}, queue, jobs)
    result = app.send_task("tests.record", args=[str(trace), "job1", 2.0], queue=queue)
    wait_for(lambda: "start job1" in trace.read_text(), 60, f"job start; log:\n{log_a}")
    worker_a.kill()  # SIGKILL: no warm shutdown, no chance to restore the message
    worker_a.wait(timeout=10)

    _, log_b, worker_b = run_worker({}, queue, jobs)
    pid_b = result.get(timeout=60, interval=0.05)
    assert pid_b == worker_b.pid != worker_a.pid
    starts = [ln for ln in trace.read_text().splitlines() if ln.startswith("start job1")]
    dones = [ln for ln in trace.read_text().splitlines() if ln.startswith("done job1")]
    assert starts == [f"start job1 {worker_a.pid}", f"start job1 {pid_b}"]
    assert dones == [f"done job1 {pid_b}"]

    stop_worker(worker_b)  # acked: a worker coming back must not run it again
    app_c, log_c, _ = run_worker({}, queue, jobs)
    round_trips(app_c, queue, 1, log_c)  # the new worker is consuming the queue
    assert trace.read_text().count("start job1") == 2


def _service_round_trip(run_worker, url: str) -> None:
    queue = f"test.{uuid.uuid4().hex}"
    app, log, _ = run_worker({"DRLAAS_BROKER": url}, queue)
    try:
        times = round_trips(app, queue, 3, log)
        assert max(times) < 5, times
    finally:
        with app.connection_for_write() as conn:  # leave no queue behind on the shared server
            try:
                conn.default_channel.queue_delete(queue)
            except Exception:  # noqa: BLE001 - cleanup best effort
                pass


def test_redis_broker_round_trip(run_worker) -> None:
    if not port_open("127.0.0.1", 6379):
        pytest.skip("no Redis listening on 127.0.0.1:6379")
    _service_round_trip(run_worker, "redis://127.0.0.1:6379/0")


def test_amqp_broker_round_trip(run_worker) -> None:
    if not port_open("127.0.0.1", 5672):
        pytest.skip("no RabbitMQ listening on 127.0.0.1:5672")
    _service_round_trip(run_worker, "amqp://guest:guest@127.0.0.1:5672//")


def test_embedded_config_uses_the_fast_transport_and_sqlite_files(tmp_path: Path) -> None:
    s = load_settings(data_dir=tmp_path)
    app = make_celery(s)
    with app.connection_for_write() as conn:
        assert conn.transport.polling_interval == EMBEDDED_POLLING_INTERVAL_S
        assert conn.transport.driver_name == "sqlalchemy"
    assert app.conf.result_backend == f"db+sqlite:///{tmp_path.resolve() / 'results.sqlite'}"


def test_job_defaults_follow_celery_guidance_for_long_jobs(settings: Settings) -> None:
    conf = make_celery(settings).conf
    assert conf.task_acks_late and conf.task_reject_on_worker_lost
    assert conf.worker_prefetch_multiplier == 1
    assert conf.task_serializer == conf.result_serializer == "json"
    assert list(conf.accept_content) == ["json"] and list(conf.result_accept_content) == ["json"]


def test_pickle_payloads_are_refused(settings: Settings) -> None:
    from kombu.exceptions import ContentDisallowed
    from kombu.serialization import dumps, loads

    conf = make_celery(settings).conf
    ctype, enc, data = dumps({"a": 1}, serializer="pickle")
    with pytest.raises(ContentDisallowed):
        loads(data, ctype, enc, accept=conf.accept_content)


def test_redis_and_amqp_configs(tmp_path: Path) -> None:
    redis = broker_config(load_settings(data_dir=tmp_path, broker="redis://127.0.0.1:6379/2"))
    assert redis["broker_url"] == redis["result_backend"] == "redis://127.0.0.1:6379/2"
    # acks_late jobs longer than the visibility timeout would be delivered twice
    assert redis["broker_transport_options"]["visibility_timeout"] >= 6 * 3600
    amqp = broker_config(load_settings(data_dir=tmp_path, broker="amqp://guest:guest@h:5672//"))
    assert amqp["broker_url"].startswith("amqp://")
    # results in their own SQLite file, never in the platform database file
    assert amqp["result_backend"] == f"db+sqlite:///{tmp_path.resolve() / 'results.sqlite'}"
    pg = broker_config(
        load_settings(
            data_dir=tmp_path,
            broker="amqp://guest:guest@h:5672//",
            database="postgresql://postgres@127.0.0.1/test",
        )
    )
    assert pg["result_backend"] == "db+postgresql+psycopg://postgres@127.0.0.1/test"


def test_worker_queue_is_per_checksummed_address() -> None:
    addr = "0x7e5f4552091a69125d5dfcb7b8c2659029395bdf"
    assert worker_queue(addr) == worker_queue(addr.upper().replace("0X", "0x"))
    assert worker_queue(addr) == "worker.0x7E5F4552091A69125d5DfCb7b8C2659029395Bdf"
    with pytest.raises(ValueError, match="not an Ethereum address"):
        worker_queue("bob")


def test_a_detached_embedded_channel_still_settles_its_messages(tmp_path: Path) -> None:
    """kombu's ``close_channel`` sets ``channel.connection = None``; a late ack (or the QoS
    restore at shutdown) must still reach the row, not fail on ``connection.client``."""
    from kombu import Connection

    from backend.celery_app import EmbeddedSQLATransport

    with Connection(
        f"sqlite:///{tmp_path / 'broker.sqlite'}", transport=EmbeddedSQLATransport
    ) as conn:
        channel = conn.channel()
        channel.queue_declare("q")
        for body in ("first", "second"):
            channel.basic_publish(channel.prepare_message(body), "", "q")
        acked, restored = channel.basic_get("q"), channel.basic_get("q")
        conn.transport.close_channel(channel)
        assert channel.connection is None
        channel.basic_ack(acked.delivery_tag)
        channel._restore(restored)  # what the QoS restore does for an unacked message

        fresh = conn.channel()
        again = fresh.basic_get("q")
        assert again is not None and again.body == b"second"  # restored, visible in place
        assert fresh.basic_get("q") is None  # the acked one is gone for good

        # A channel detached before its first database use (no session yet) still restores.
        late = conn.channel()
        conn.transport.close_channel(late)
        late._restore(again)
        assert fresh.basic_get("q").body == b"second"


def test_an_embedded_queue_created_by_another_process_meanwhile_is_used(tmp_path: Path) -> None:
    """Two processes declaring one new queue at once: the other one's row lands between this
    channel's look-up and its insert (replayed here with a second connection at the moment of
    the INSERT). The declare must use that row, not die on the UNIQUE constraint."""
    import sqlite3

    from kombu import Connection
    from sqlalchemy import event

    from backend.celery_app import EmbeddedSQLATransport

    db = tmp_path / "broker.sqlite"
    with Connection(f"sqlite:///{db}", transport=EmbeddedSQLATransport) as conn:
        channel = conn.channel()
        channel.queue_declare("warm-up")  # creates the tables
        raced: list[str] = []

        def other_process_first(_conn, _cursor, statement, params, _context, _many) -> None:
            if statement.startswith("INSERT INTO kombu_queue") and params[0] == "q":
                with sqlite3.connect(db) as other:
                    other.execute("INSERT INTO kombu_queue (name) VALUES ('q')")
                raced.append(statement)

        engine = channel.session.get_bind()
        event.listen(engine, "before_cursor_execute", other_process_first)
        try:
            channel.queue_declare("q")
        finally:
            event.remove(engine, "before_cursor_execute", other_process_first)
        assert raced, "the race was not replayed"
        channel.basic_publish(channel.prepare_message("after the race"), "", "q")
        message = channel.basic_get("q")
        assert message.body == b"after the race"
        channel.basic_ack(message.delivery_tag)
        rows = channel.session.query(channel.queue_cls).filter(channel.queue_cls.name == "q")
        assert rows.count() == 1
