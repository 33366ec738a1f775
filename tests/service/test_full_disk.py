"""A full data volume, on every backend: a job whose write finds no room fails once with
"data volume full" (no retry, nothing re-sent, no file of it left), an upload that finds no
room makes no job, and ``/readyz`` says so. The volume is a small tmpfs the test mounts as
the artifacts folder (root only; elsewhere the tests are skipped, saying why).

Also, stored job errors stay short whatever the failure said (repeated lines folded, then
capped), and a failed tiled forest of more tiles than a statement may bind can be canceled
(``DELETE``: once a 503 for ever on PostgreSQL)."""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
from service_harness import Server

from farm.error_text import MAX_ERROR_CHARS
from farm.settings import FarmSettings
from farm.store import JobStore
from farm.tiles import tile_job_ids
from schemas.jobs import JobState

FOREST = {"preset": "almond", "trees": 3, "seed": 7, "format": "usdc", "frames": 2}
ROOM = 64 << 10  # bytes left free: no scene and no upload of the tests fits
ENV = {"FOREST_MIN_FREE_MB": "1"}
MakeServer = Callable[..., Server]  # /readyz: ready with a MiB free, not with ROOM


@pytest.fixture
def volume(tmp_path: Path) -> Iterator[Path]:
    """A 32 MiB tmpfs of the test's own, unmounted afterwards."""
    folder = tmp_path / "volume"
    folder.mkdir()
    if os.geteuid() != 0:
        reason = "mounting a tmpfs needs root"
        print(f"skipped: {reason}")
        pytest.skip(reason)
    mount = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=32m", "tmpfs", str(folder)],
        capture_output=True,
        text=True,
    )
    if mount.returncode != 0:
        reason = f"mount -t tmpfs not permitted here: {mount.stderr.strip()}"
        print(f"skipped: {reason}")
        pytest.skip(reason)
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def fill(folder: Path, leave: int = ROOM) -> Path:
    """A file taking all of ``folder``'s volume but ``leave`` bytes."""
    st = os.statvfs(folder)
    filler = folder / "filler"
    with open(filler, "wb") as f:
        os.posix_fallocate(f.fileno(), 0, st.f_bavail * st.f_frsize - leave)
    return filler


def served_on(volume: Path, backend: dict[str, str], make_server: MakeServer, data: Path) -> Server:
    return make_server(backend | ENV | {"FOREST_ARTIFACTS_DIR": str(volume)}, data=data)


def left_behind(volume: Path) -> list[str]:
    """What is on the volume besides the filler (job folders, scratch folders)."""
    return sorted(p.name for p in volume.iterdir() if p.name != "filler")


def test_write_on_a_full_volume_fails_the_job_once(
    backend: dict[str, str], make_server: MakeServer, volume: Path, tmp_path: Path
) -> None:
    server = served_on(volume, backend, make_server, tmp_path / "data")
    filler = fill(volume)
    r = server.post("/v1/forests", FOREST)
    assert r.status_code == 202, r.text
    job = server.wait(r.json()["id"], timeout=120)
    assert (job["state"], job["error"], job["attempts"]) == ("failed", "data volume full", 1), job
    assert job["artifacts"] == []
    # nothing re-sent or retried meanwhile: a later look finds it as it was
    time.sleep(1.5)  # a few reaper rounds (FOREST_REAPER_INTERVAL_S 0.5); no bound asserted
    again = server.get(f"/v1/jobs/{job['id']}").json()
    assert (again["state"], again["attempts"]) == ("failed", 1), again
    assert left_behind(volume) == [], "no half artifact, no scratch folder"
    ready = httpx.get(f"{server.url}/readyz", timeout=30)
    assert ready.status_code == 503, ready.text
    body = ready.json()
    assert body["checks"]["data_volume"].startswith("full"), body
    assert body["data_free_bytes"] <= 2 * ROOM, body

    # room again: ready again, and the same request completes
    filler.unlink()
    assert httpx.get(f"{server.url}/readyz", timeout=30).status_code == 200
    r = server.post("/v1/forests", FOREST)
    assert server.wait(r.json()["id"], timeout=120)["state"] == "completed"


def test_upload_on_a_full_volume_makes_no_job(
    backend: dict[str, str], make_server: MakeServer, volume: Path, tmp_path: Path
) -> None:
    server = served_on(volume, backend, make_server, tmp_path / "data")
    fill(volume)
    scene = b"#usda 1.0\n" + b"# padding\n" * (4 * ROOM // 10)
    r = httpx.post(
        f"{server.url}/v1/renders/upload",
        files={"scene": ("big.usda", scene)},
        data={"width": "48", "height": "32"},
        timeout=60,
    )
    assert r.status_code == 507, r.text
    assert "data volume full" in r.text
    jobs = server.get("/v1/jobs?kind=render").json()
    assert jobs["total"] == 0, jobs  # no render job left for the reaper to send
    assert left_behind(volume) == []
    time.sleep(1.0)  # reaper rounds: still none
    assert server.get("/v1/jobs?kind=render").json()["total"] == 0


def test_a_job_store_without_room_is_507_not_an_outage(
    make_server: MakeServer, volume: Path
) -> None:
    """The embedded store's SQLite file on the full volume: a new job cannot be written. That
    is the volume, as ``/readyz`` says, not a store that is away (it was 503 with
    Retry-After, "the job store is unavailable")."""
    server = make_server(ENV, data=volume)
    fill(volume, leave=0)
    r = server.post("/v1/forests", FOREST)
    assert r.status_code == 507, r.text
    assert r.json()["detail"] == "data volume full" and "retry-after" not in r.headers
    assert server.get("/v1/jobs").status_code == 200  # reading still works
    (volume / "filler").unlink()
    r = server.post("/v1/forests", FOREST)
    assert r.status_code == 202, r.text


# -- stored errors --------------------------------------------------------------------------

PXR_LINES = (
    "\n\tError in 'ArFilesystemWritableAsset::Write' at line 78: 'Error occurred writing "
    "file: No space left on device'\n\tError in 'WriteToAsset' at line 242: 'Failed writing "
    "usdc data'"
)


@pytest.fixture
def store_server(
    backend: dict[str, str], make_server: MakeServer, tmp_path: Path
) -> Iterator[tuple[Server, JobStore]]:
    data = tmp_path / "data"
    # the tests write job rows themselves: no reaper round may pump one of them (held) to a
    # worker before the test claims it
    server = make_server(backend | {"FOREST_REAPER_INTERVAL_S": "600"}, data=data)
    url = FarmSettings(data_dir=data, database_url=backend.get("FOREST_DATABASE_URL")).db_url
    store = JobStore(url)
    try:
        yield server, store
    finally:
        store.engine.dispose()


def test_stored_errors_are_capped_and_folded(store_server: tuple[Server, JobStore]) -> None:
    server, store = store_server
    ids = []
    for n in range(6):  # as the report had it: 6 jobs of ~1 MB of pxr errors each
        row, _ = store.create("render", {"n": n}, 3)
        claim = store.claim(row.id, "test-worker", 30)
        assert claim is not None
        error = PXR_LINES * 6000 if n % 2 else "x" * (1 << 20)
        if n == 0:  # queued again (with its error), then canceled: no worker runs it
            assert store.retry(claim, error)
            store.cancel_family(row.id)
        else:
            assert store.finish(claim, JobState.FAILED, error=error)
        ids.append(row.id)
    page = server.get("/v1/jobs?limit=200")
    assert page.status_code == 200
    assert len(page.content) < 64 << 10, len(page.content)
    errors = {j["id"]: j["error"] for j in page.json()["items"]}
    assert all(len(errors[i]) <= MAX_ERROR_CHARS for i in ids), [len(errors[i]) for i in ids]
    folded = errors[ids[1]]
    assert "No space left on device" in folded and "(repeated 6000 times)" in folded, folded
    assert errors[ids[2]].endswith("more characters)"), errors[ids[2]][-80:]


def test_failed_tiled_forest_of_many_tiles_can_be_deleted(
    store_server: tuple[Server, JobStore],
) -> None:
    """72,900 tiles: more ids than PostgreSQL (65,535) or SQLite (32,766) binds in one
    statement; the job failed as the issue's did, with its SQL as its error."""
    server, store = store_server
    params = {"preset": "almond", "trees": 10, "area": [2700.0, 2700.0], "tile_size": 10.0}
    row, _ = store.create("forest", params, 3)
    assert len(tile_job_ids(row.id, params)) == 72_900
    sql = "INSERT INTO jobs (id, kind) VALUES " + ", ".join(["(%s, %s)"] * 200_000)
    # claimed first: held, the job is the server's fair window's to send to its workers
    claim = store.claim(row.id, "test-worker", 30)
    assert claim is not None
    error = f"OperationalError: number of parameters\n[SQL: {sql}]"
    assert store.finish(claim, JobState.FAILED, error=error)
    r = httpx.delete(f"{server.url}/v1/jobs/{row.id}", timeout=60)
    assert r.status_code == 200, r.text
    assert r.json()["state"] == JobState.FAILED  # a finished job stays as it ended
    assert len(r.json()["error"]) <= MAX_ERROR_CHARS
