"""``POST /v1/trees`` through the worker pool (issue 26, defect 6): the tree is a ``tree`` job
that a worker makes under the job limits; the API waits for it and answers the file (200), or
the job (202) when it is not done in time. The API process's memory stays flat over many
trees, and several medium trees at once queue on the workers rather than add up in the API.
On the embedded server and on PostgreSQL with RabbitMQ and with Redis."""

from __future__ import annotations

import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import pytest
from service_harness import Server, reference_scene, served, tree_file

SMALL = {"preset": "almond", "format": "usdc"}
# a tree of one piece: a fraction of a second of work, so 100 of them measure the API alone
TINY = {"grammar": {"axiom": "A", "rules": {"A": [{"piece": "I", "successors": [None]}]}}}
# ~240 MB of peak memory and a few seconds when made in one process (an 18 MB .usdc)
MEDIUM = {"preset": "oak", "frames": 24, "segments": 2, "format": "usdc"}
MIB = 1 << 20


@pytest.fixture(scope="module")
def server(backend: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    yield from served(tmp_path_factory.mktemp("serve-trees"), backend)


def status_kib(pid: int, field: str) -> int:
    """``VmRSS`` (resident now) or ``VmHWM`` (the most resident so far) of a process, in KiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{field}:"):
            return int(line.split()[1])
    raise AssertionError(f"no {field} in /proc/{pid}/status")


def api_pid(server: Server) -> int:
    assert server.proc is not None and server.api_workers == 1  # the API runs in that process
    return server.proc.pid


def test_season_reaches_the_tree(server: Server, tmp_path: Path) -> None:
    """``season`` (the CLI's --season) colours the leaves: the library's autumn almond, not
    its summer one."""
    body = SMALL | {"seed": 12, "season": "autumn", "skinned": False}
    got = tree_file(server, body).content
    assert got == reference_scene(tmp_path, body, "tree")
    assert got != reference_scene(tmp_path, body | {"season": "summer"}, "tree")


def test_tree_is_made_by_a_job(server: Server, tmp_path: Path) -> None:
    body = SMALL | {"seed": 11}
    r = server.post("/v1/trees", body)
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "model/vnd.usd"
    assert r.headers["content-disposition"] == 'attachment; filename="almond-11.usdc"'
    assert r.content == reference_scene(tmp_path, body, "tree")
    jobs = server.get("/v1/jobs?kind=tree&limit=200").json()["items"]
    job = next(j for j in jobs if j["params"]["seed"] == 11)
    assert job["state"] == "completed" and job["worker"] is None, job
    assert job["result"]["scene"] == "tree.usdc" and job["result"]["pieces"] > 0
    # the file was the answer: deleted once sent (the job says when)
    for _ in range(50):
        job = server.get(f"/v1/jobs/{job['id']}").json()
        if job["artifacts_deleted_at"]:
            break
        time.sleep(0.1)
    assert job["artifacts"] == [] and job["artifacts_deleted_at"], job


def test_respond_async_answers_the_job(server: Server, tmp_path: Path) -> None:
    body = SMALL | {"seed": 12, "format": "usdz"}
    r = server.post("/v1/trees", body, headers={"Prefer": "respond-async"})
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/v1/jobs/{job['id']}"
    assert job["kind"] == "tree" and job["params"]["seed"] == 12
    assert set(job) == set(server.get(r.headers["location"]).json())  # the jobs routes' shape
    done = server.wait(job["id"])
    assert done["state"] == "completed", done
    assert [a["name"] for a in done["artifacts"]] == ["tree.usdz"]
    file = server.get(done["artifacts"][0]["url"])
    assert file.headers["content-type"] == "model/vnd.usdz+zip"
    assert file.content == reference_scene(tmp_path, body, "tree")  # the very bytes of a 200


def test_a_tree_takes_a_priority(server: Server) -> None:
    r = server.post("/v1/trees", SMALL | {"priority": 9}, headers={"Prefer": "respond-async"})
    assert r.status_code == 202, r.text
    assert r.json()["priority"] == 9
    assert server.wait(r.json()["id"])["state"] == "completed"


def test_api_memory_stays_flat_over_many_trees(server: Server) -> None:
    """100 trees (4 clients): the API's resident memory grows by less than 100 MiB after a
    warm-up, and each tree was a job (the API made them itself before)."""
    pid = api_pid(server)
    for seed in range(4):  # warm-up: connections, threads, first-request caches
        tree_file(server, TINY | {"seed": 100 + seed})
    before = status_kib(pid, "VmRSS")

    def one(seed: int) -> int:
        return tree_file(server, TINY | {"seed": seed}).status_code

    with ThreadPoolExecutor(4) as pool:
        assert set(pool.map(one, range(1000, 1100))) == {200}
    grown = (status_kib(pid, "VmRSS") - before) * 1024
    assert grown < 100 * MIB, f"API RSS grew {grown / MIB:.0f} MiB over 100 trees"
    total = server.get("/v1/jobs?kind=tree&state=completed&limit=1").json()["total"]
    assert total >= 104


def test_concurrent_medium_trees_queue_on_the_workers(server: Server, tmp_path: Path) -> None:
    """4 medium trees at once (each ~240 MB made in one process): the API's peak memory
    (VmHWM) rises by less than 100 MiB; the workers take them in turn."""
    pid = api_pid(server)
    tree_file(server, SMALL | {"seed": 5})  # the API warm, before its high-water mark is read
    peak_before = status_kib(pid, "VmHWM")

    with ThreadPoolExecutor(4) as pool:
        files = list(pool.map(lambda s: tree_file(server, MEDIUM | {"seed": s}), range(4)))
    assert len({f.content for f in files}) == 4
    assert files[0].content == reference_scene(tmp_path, MEDIUM | {"seed": 0}, "tree")
    risen = (status_kib(pid, "VmHWM") - peak_before) * 1024
    assert risen < 100 * MIB, f"API peak RSS rose {risen / MIB:.0f} MiB over 4 medium trees"


# seconds of work (~1 GB if made in one process): never done within the waits below
SLOW = {"preset": "oak", "frames": 48, "segments": 4, "format": "usdz"}


def test_not_done_in_time_answers_the_job(server: Server) -> None:
    r = server.post("/v1/trees", SLOW | {"seed": 1}, headers={"Prefer": "wait=0.2"})
    assert r.status_code == 202, r.text
    assert r.json()["kind"] == "tree" and r.json()["state"] in ("queued", "active")
    assert r.headers["location"] == f"/v1/jobs/{r.json()['id']}"
    # canceled: the test needs no more of it (a queued one at once, a running one is killed)
    gone = httpx.delete(f"{server.url}{r.headers['location']}", headers=server.headers, timeout=30)
    assert gone.status_code == 200, gone.text
    assert server.wait(r.json()["id"])["state"] == "canceled"


def test_a_client_that_hangs_up_cancels_its_tree(server: Server) -> None:
    body = SLOW | {"seed": 2}
    with pytest.raises(httpx.ReadTimeout):
        httpx.post(f"{server.url}/v1/trees", json=body, timeout=httpx.Timeout(30, read=0.5))
    job: dict[str, object] = {}
    for _ in range(300):  # the request may still be on its way in: look until its job shows
        jobs = server.get("/v1/jobs?kind=tree&limit=200").json()["items"]
        job = next(
            (j for j in jobs if j["params"]["frames"] == 48 and j["params"]["seed"] == 2), {}
        )
        if job:
            break
        time.sleep(0.1)
    assert job, "no job for the request"
    assert server.wait(str(job["id"]))["state"] == "canceled"


@pytest.mark.parametrize(
    ("prefer", "wait_s"),
    [
        (None, 30.0),
        ("respond-async", 0.0),
        ("wait=5", 5.0),
        ('wait="2.5", handling=lenient', 2.5),
        ("wait=90", 30.0),  # never longer than the server's
        ("wait=soon", 30.0),  # unreadable: ignored
        ("handling=strict; x=1, RESPOND-ASYNC", 0.0),
    ],
)
def test_prefer_header(prefer: str | None, wait_s: float) -> None:
    from service.routes.trees import wait_preference

    assert wait_preference(prefer, 30.0) == wait_s
