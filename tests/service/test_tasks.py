"""A job's delivery run in-process (``worker.jobs.tasks.execute``) with stand-in task kinds, each
attempt in its supervised child process: retries up to the attempt cap then failed with the
error, bad input failed at once, a crash or a memory limit of the child failed at once (not
a lost worker), cancel kills the child, a child holding its GIL keeps the lease, a duplicate
delivery skipped. The job store is SQLite in a temporary folder; the broker is replaced by a
recorder. (Kinds are module functions: the child imports them by name.)"""

from __future__ import annotations

import errno
import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from job_hooks import hold_gil as hold_gil_for

from farm import tiles
from farm.db import migrate
from farm.settings import FarmSettings, override_settings
from farm.store import JobStore
from forest.errors import ForestError
from worker.jobs import tasks
from worker.jobs.context import JobContext, Outcome
from worker.jobs.supervise import scrub_paths
from worker.jobs.tasks import execute


@pytest.fixture
def store(tmp_path: Path) -> Iterator[JobStore]:
    settings = FarmSettings(
        data_dir=tmp_path,
        max_attempts=2,
        retry_delay_s=0,
        lease_s=1.0,
        heartbeat_s=0.2,
        job_memory_mb=1024,
    )
    override_settings(settings)
    migrate(settings.db_url)
    yield JobStore(settings.db_url)
    override_settings(None)
    tasks._runtime = None


def broken(ctx: JobContext) -> Outcome:
    raise RuntimeError(f"disk on fire at {ctx.scratch}")


def bad_input(ctx: JobContext) -> Outcome:
    raise ForestError("no such symbol", path="rules.A[0].successors[0].symbol")


def write_one(ctx: JobContext) -> Outcome:
    ctx.report("write", 0.5)
    out = ctx.scratch / "scene.usda"
    out.write_text("#usda 1.0\n")
    return Outcome({"scene.usda": out}, {"ok": True})


def crash_reading(ctx: JobContext) -> Outcome:
    ctx.report("read", 0.1)
    os.abort()


def hog_memory(ctx: JobContext) -> Outcome:
    ctx.report("read", 0.1)
    blocks = [np.ones(1 << 27) for _ in range(64)]  # 64 GiB, far over the 1 GiB limit
    return Outcome({}, {"n": len(blocks)})


def hold_gil(ctx: JobContext) -> Outcome:
    hold_gil_for(4.0)  # four lease periods in one C call that keeps the GIL
    return write_one(ctx)


def sleep_long(ctx: JobContext) -> Outcome:
    ctx.report("render", 0.3)
    hold_gil_for(60.0)
    return write_one(ctx)


def test_retries_then_fails_with_the_error(
    store: JobStore, monkeypatch: pytest.MonkeyPatch
) -> None:
    sent: list[tuple[str, str]] = []
    monkeypatch.setattr(
        tasks.runtime().dispatcher,
        "send",
        lambda job_id, kind, countdown=None, pool=None: sent.append((job_id, kind)),
    )
    row, _ = store.create("forest", {}, max_attempts=2)
    assert execute(row.id, {"forest": broken}) == "retry"
    assert sent == [(row.id, "forest")]  # sent again, after retry_delay_s
    job = store.get(row.id)
    assert job is not None and (job.state, job.attempts) == ("queued", 1)
    assert execute(row.id, {"forest": broken}) == "failed"
    job = store.get(row.id)
    assert job is not None and job.state == "failed" and job.attempts == 2
    assert job.error is not None and job.error.startswith("RuntimeError: disk on fire at .")
    assert "/" not in job.error  # no server path


def test_bad_input_fails_at_once(store: JobStore) -> None:
    row, _ = store.create("forest", {}, max_attempts=2)
    assert execute(row.id, {"forest": bad_input}) == "failed"
    job = store.get(row.id)
    assert job is not None and job.attempts == 1
    assert job.error == "rules.A[0].successors[0].symbol: no such symbol"


def test_completes_once_and_publishes(store: JobStore, tmp_path: Path) -> None:
    row, _ = store.create("forest", {}, max_attempts=2)
    assert execute(row.id, {"forest": write_one}) == "completed"
    assert execute(row.id, {"forest": write_one}) == "skipped"  # a duplicate delivery
    assert (tmp_path / "artifacts" / row.id / "scene.usda").read_text() == "#usda 1.0\n"
    assert not list((tmp_path / "artifacts").glob(".*"))  # no scratch left behind
    job = store.get(row.id)
    assert job is not None and job.artifacts == ["scene.usda"] and job.result == {"ok": True}


def no_room(ctx: JobContext) -> Outcome:
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(ctx.scratch / "scene.usdc"))


def no_room_in_pxr(ctx: JobContext) -> Outcome:
    line = "\n\tError in 'Write' at line 78: 'Error occurred writing file: No space left on device'"
    raise RuntimeError(line * 5000)  # as pxr's Tf.ErrorException reads


def write_two(ctx: JobContext) -> Outcome:
    files = {name: ctx.scratch / name for name in ("a.usda", "b.usda")}
    for path in files.values():
        path.write_text("#usda 1.0\n")
    return Outcome(files, {})


@pytest.mark.parametrize("kind", [no_room, no_room_in_pxr])
def test_no_room_fails_at_once(store: JobStore, kind: object) -> None:
    row, _ = store.create("forest", {}, max_attempts=2)
    assert execute(row.id, {"forest": kind}) == "failed"  # type: ignore[dict-item]
    job = store.get(row.id)
    assert job is not None and (job.error, job.attempts) == ("data volume full", 1)


def test_no_room_to_publish_leaves_no_file(
    store: JobStore, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    artifacts = tasks.runtime().artifacts
    publish = artifacts.publish

    def publish_a_only(job_id: str, src: Path, name: str) -> Path:
        if name == "b.usda":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return publish(job_id, src, name)

    monkeypatch.setattr(artifacts, "publish", publish_a_only)
    row, _ = store.create("forest", {}, max_attempts=2)
    assert execute(row.id, {"forest": write_two}) == "failed"
    job = store.get(row.id)
    assert job is not None and (job.error, job.attempts) == ("data volume full", 1)
    root = tmp_path / "artifacts"
    assert not list(root.glob(f"{row.id}/*")), "no half set of artifacts"
    assert not list(root.glob(".*")), "no scratch left behind"


def test_reader_crash_is_a_permanent_failure(store: JobStore) -> None:
    row, _ = store.create("render", {}, max_attempts=2)
    assert execute(row.id, {"render": crash_reading}) == "failed"
    job = store.get(row.id)
    assert job is not None and job.attempts == 1
    assert job.error == "the scene could not be read: the USD reader crashed (SIGABRT)"


def test_memory_limit_is_a_permanent_failure(store: JobStore) -> None:
    row, _ = store.create("render", {}, max_attempts=2)
    assert execute(row.id, {"render": hog_memory}) == "failed"
    job = store.get(row.id)
    assert job is not None and job.attempts == 1
    assert job.error == "the job ran out of memory (its limit is 1024 MiB)"


def test_a_child_holding_its_gil_keeps_the_lease(store: JobStore) -> None:
    row, _ = store.create("forest", {}, max_attempts=2)
    beats: list[object] = []

    def watch() -> None:  # the lease must be extended while the child holds its GIL
        for _ in range(30):
            job = store.get(row.id)
            if job is not None and job.heartbeat_at is not None:
                beats.append(job.heartbeat_at)
            time.sleep(0.1)

    t = threading.Thread(target=watch)
    t.start()
    assert execute(row.id, {"forest": hold_gil}) == "completed"
    t.join()
    job = store.get(row.id)
    assert job is not None and job.attempts == 1 and job.state == "completed"
    assert len(set(beats)) >= 5  # heartbeats went on during the 4 s C call


def test_cancel_kills_the_child_within_seconds(store: JobStore) -> None:
    row, _ = store.create("render", {}, max_attempts=2)

    def cancel_soon() -> None:
        time.sleep(1.0)
        tiles.cancel(store, row.id)

    threading.Thread(target=cancel_soon).start()
    t0 = time.monotonic()
    assert execute(row.id, {"render": sleep_long}) == "canceled"
    assert time.monotonic() - t0 < 5.0  # the child's 60 s C call was cut short
    job = store.get(row.id)
    assert job is not None and job.state == "canceled" and job.artifacts == []


def test_scrub_paths() -> None:
    msg = "no such file @/srv/forest/artifacts/ab/upload.usdc@ (at /tmp/x/y.usda: line 3)"
    assert scrub_paths(msg) == "no such file @upload.usdc@ (at y.usda: line 3)"
    # a scratch folder's name holds an @ (process and host): the whole path goes
    msg = "/srv/data/artifacts/.b8fe.15189@vm~4026.rky2/tiles/bark_array.tif: 4 slices"
    assert scrub_paths(msg) == "bark_array.tif: 4 slices"
