"""Celery configuration per broker: Redis gets a visibility timeout that leaves recovery to the
reaper and a key prefix that keeps clusters sharing a database apart; the others get neither.
On the real brokers (RabbitMQ, Redis on loopback) a job's message lands on its kind's queue
only."""

from __future__ import annotations

import sqlite3
import threading
import time
import uuid
from contextlib import closing
from pathlib import Path

import pytest
from pydantic import ValidationError
from service_harness import (
    RABBIT,
    RABBIT_URL,
    REDIS,
    REDIS_URL,
    delete_rabbit_queues,
    delete_redis_keys,
    require_server,
)

from farm.dispatch import QUEUES, Dispatcher, make_celery
from farm.settings import FarmSettings


@pytest.mark.parametrize(
    "url", ["redis://127.0.0.1:6379/3", "rediss://h:6380/0", "redis+socket:///tmp/redis.sock"]
)
def test_redis_broker_options(tmp_path: Path, url: str) -> None:
    s = FarmSettings(data_dir=tmp_path, broker_url=url, queue_prefix="blue.")
    assert s.is_redis
    app = make_celery(s)
    assert app.conf.broker_transport_options == {
        "visibility_timeout": 3600.0,
        "global_keyprefix": "blue.",
    }
    assert app.conf.task_acks_late and app.conf.task_reject_on_worker_lost
    assert app.conf.worker_prefetch_multiplier == 1
    assert [q.name for q in app.conf.task_queues] == [f"blue.{q}" for q in QUEUES]
    unprefixed = make_celery(FarmSettings(data_dir=tmp_path, broker_url=url))
    assert unprefixed.conf.broker_transport_options == {"visibility_timeout": 3600.0}


LOCK_HELD_S = 6


def test_amqp_gets_no_transport_options(tmp_path: Path) -> None:
    s = FarmSettings(data_dir=tmp_path, broker_url="amqp://guest:guest@127.0.0.1:5672//")
    assert not s.is_redis
    assert not make_celery(s).conf.broker_transport_options


def test_embedded_broker_waits_for_a_lock_in_wal_mode(tmp_path: Path) -> None:
    """The embedded broker's file in WAL mode (polls never block a send) and kombu's engine
    waiting as long as the job store for a lock (sqlite3's 5 s made a send under load fail)."""
    s = FarmSettings(data_dir=tmp_path, queue_prefix="blue.")
    app = make_celery(s)
    assert app.conf.broker_transport_options == {"connect_args": {"timeout": 30}}
    with closing(sqlite3.connect(tmp_path / "broker.sqlite")) as conn:
        assert conn.execute("PRAGMA journal_mode").fetchone() == ("wal",)
    with app.connection_for_write() as conn:
        queue = app.conf.task_queues[0]
        with conn.Producer() as producer:  # the tables made, as a first send makes them
            producer.publish(
                {"n": 0}, exchange=queue.exchange, routing_key=queue.routing_key, declare=[queue]
            )
        held = threading.Event()

        def hold_the_write_lock() -> None:  # another writer, for longer than sqlite3's 5 s
            with closing(sqlite3.connect(tmp_path / "broker.sqlite")) as other:
                other.execute("BEGIN IMMEDIATE")
                held.set()
                time.sleep(LOCK_HELD_S)
                other.rollback()

        writer = threading.Thread(target=hold_the_write_lock)
        writer.start()
        held.wait(10)
        start = time.monotonic()
        with conn.Producer() as producer:
            producer.publish({"n": 1}, exchange=queue.exchange, routing_key=queue.routing_key)
        writer.join()
        assert time.monotonic() - start >= LOCK_HELD_S - 0.5  # it waited, and was sent


def test_redis_visibility_timeout_must_outlast_the_reaper(tmp_path: Path) -> None:
    redis = "redis://127.0.0.1:6379/0"
    with pytest.raises(ValidationError, match="broker_visibility_timeout_s"):  # 30 + 60 + 5
        FarmSettings(data_dir=tmp_path, broker_url=redis, broker_visibility_timeout_s=60)
    ok = FarmSettings(
        data_dir=tmp_path,
        broker_url=redis,
        broker_visibility_timeout_s=60,
        lease_s=5,
        requeue_after_s=15,
    )
    assert ok.broker_visibility_timeout_s == 60
    # no other broker has a visibility timeout: nothing to check
    assert FarmSettings(data_dir=tmp_path, broker_visibility_timeout_s=60)


@pytest.mark.parametrize("broker", ["RabbitMQ", "Redis"])
def test_each_kind_reaches_its_own_queue_only(tmp_path: Path, broker: str) -> None:
    addr, url = {"RabbitMQ": (RABBIT, RABBIT_URL), "Redis": (REDIS, REDIS_URL)}[broker]
    require_server(broker, addr)
    prefix = f"forest-test-{uuid.uuid4().hex[:12]}."
    d = Dispatcher(FarmSettings(data_dir=tmp_path, broker_url=url, queue_prefix=prefix))
    try:
        with d.app.connection_for_write() as conn:
            channel = conn.default_channel
            # the queues as Celery completes them, which a worker declares when it starts
            queues = [d.app.amqp.queues[prefix + name](channel) for name in QUEUES]
            for q in queues:
                q.declare()
            d.send("a" * 32, "forest")
            d.send("b" * 32, "forest")
            d.send("c" * 32, "render")  # any pool: whichever render worker is free
            d.send("d" * 32, "render", pool="gpu")
            d.send("e" * 32, "render", pool="cpu")
            d.send("f" * 32, "render", pool="cpu")

            # (Redis has no empty queue to find passively: declare again, which counts too)
            def counts() -> dict[str, int]:
                passive = broker == "RabbitMQ"
                return {
                    q.name[len(prefix) :]: q.queue_declare(passive=passive).message_count
                    for q in queues
                }

            # RabbitMQ orders a channel's frames only: the count, on another connection than
            # the publishes (unconfirmed), may come before the last is routed
            deadline = time.monotonic() + 5
            want = {"default": 2, "render": 1, "gpu": 1, "cpu": 2}
            while counts() != want and time.monotonic() < deadline:
                time.sleep(0.05)
            assert counts() == want
    finally:
        d.close()
        if broker == "Redis":
            delete_redis_keys(prefix)
        else:
            delete_rabbit_queues(prefix)
