"""``forest bench service``: latency and throughput of ``forest serve`` in a subprocess on a
temporary data folder: ``POST /v1/trees`` at several client concurrencies, and forest-job
throughput (trees/s) with 1 and 2 workers, on the embedded SQLite job store and broker or on
a real job store and broker given by URL; or (``--render-frames``) the wall time of one clip
with 1 and 2 render workers, its frame chunks run in parallel."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import NamedTuple

import httpx
import numpy as np

from schemas.jobs import JobState


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Served(NamedTuple):
    url: str
    pid: int
    """The API's process (``forest serve`` with one API process runs the API itself)."""


def rss_mib(pid: int) -> float:
    """Resident memory of a process now (``VmRSS``), MiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no VmRSS for process {pid}")


@contextmanager
def embedded_server(
    data: Path, workers: int, backends: dict[str, str] | None = None
) -> Iterator[Served]:
    """``forest serve`` with ``workers`` job workers; ``backends`` holds FOREST_DATABASE_URL
    and FOREST_BROKER_URL when not the embedded ones."""
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("FOREST_")}
    env["FOREST_DATA_DIR"] = str(data)
    env["FOREST_RATE_LIMIT"] = ""  # measures the server, not its per-key limiter (429s)
    env.update(backends or {})
    log = open(data.parent / f"{data.name}.log", "ab")  # noqa: SIM115
    proc = subprocess.Popen(
        [sys.executable, "-m", "cli", "serve", "--port", str(port), "--workers", str(workers)],
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    log.close()
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"forest serve did not start; see {log.name}")
            try:
                if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        time.sleep(1.0 if workers else 0.0)  # workers connect to the broker
        yield Served(url, proc.pid)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()


def tree_latency(
    url: str, body: dict[str, object], clients: int, requests: int
) -> dict[str, float]:
    """``requests`` POSTs spread over ``clients`` threads (one connection each)."""
    times: list[float] = []
    lock = threading.Lock()
    per = [requests // clients + (i < requests % clients) for i in range(clients)]
    errors: list[str] = []

    def run(n: int) -> None:
        with httpx.Client(base_url=url, timeout=120) as c:
            for _ in range(n):
                t0 = time.perf_counter()
                r = c.post("/v1/trees", json=body)
                dt = time.perf_counter() - t0
                if r.status_code != 200:
                    errors.append(f"{r.status_code} {r.text[:200]}")
                with lock:
                    times.append(dt)

    with httpx.Client(base_url=url, timeout=120) as c:  # warm-up (imports, caches)
        c.post("/v1/trees", json=body)
    start = time.perf_counter()
    threads = [threading.Thread(target=run, args=(n,)) for n in per if n]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - start
    if errors:
        raise RuntimeError(f"{len(errors)} failed request(s), first: {errors[0]}")
    ms = np.array(times) * 1000
    return {
        "p50_ms": float(np.percentile(ms, 50)),
        "p99_ms": float(np.percentile(ms, 99)),
        "rps": len(ms) / wall,
    }


def job_throughput(url: str, body: dict[str, object], jobs: int) -> dict[str, float]:
    with httpx.Client(base_url=url, timeout=60) as c:

        def count(state: str) -> int:  # one cheap count: polling must not eat the workers' CPU
            return int(c.get("/v1/jobs", params={"state": state, "limit": 1}).json()["total"])

        # a job store of its own may hold earlier runs' jobs: count from what is there
        done0, bad0 = count(JobState.COMPLETED), count(JobState.FAILED)
        start = time.perf_counter()
        ids = [
            c.post("/v1/forests", json=body | {"seed": 1000 + i}).json()["id"] for i in range(jobs)
        ]
        while True:
            if count(JobState.FAILED) > bad0:
                raise RuntimeError(f"{count(JobState.FAILED) - bad0} job(s) failed")
            if count(JobState.COMPLETED) - done0 >= len(ids):
                break
            time.sleep(0.1)
        wall = time.perf_counter() - start
    trees = jobs * int(body["trees"])  # type: ignore[call-overload]
    return {"seconds": wall, "jobs_per_s": jobs / wall, "trees_per_s": trees / wall}


def clip_wall_time(url: str, forest: dict[str, object], render: dict[str, object]) -> float:
    """A forest job, then the wall time of a render job of it, from its submission until it
    completed (its frame chunks run, its clip assembled)."""
    with httpx.Client(base_url=url, timeout=60) as c:

        def finished(job_id: str, timeout_s: float = 3600.0) -> dict[str, object]:
            # a job no worker takes (its queue unconsumed) would wait for ever: give up
            deadline = time.monotonic() + timeout_s
            while True:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"job {job_id} not done after {timeout_s:.0f} s")
                job = c.get(f"/v1/jobs/{job_id}").json()
                if job["state"] not in (JobState.QUEUED, JobState.ACTIVE):
                    if job["state"] != JobState.COMPLETED:
                        raise RuntimeError(f"job {job_id} {job['state']}: {job.get('error')}")
                    return dict(job)
                time.sleep(0.05)

        r = c.post("/v1/forests", json=forest)
        r.raise_for_status()
        forest_id = r.json()["id"]
        finished(forest_id)
        start = time.perf_counter()
        r = c.post("/v1/renders", json=render | {"forest_job": forest_id})
        r.raise_for_status()
        finished(r.json()["id"])
        return time.perf_counter() - start


def _backends(database_url: str | None, broker_url: str | None) -> dict[str, str]:
    backends = {}
    if database_url:
        backends["FOREST_DATABASE_URL"] = database_url
    if broker_url:
        backends["FOREST_BROKER_URL"] = broker_url
        if os.environ.get("FOREST_QUEUE_PREFIX"):  # a broker shared with other farms
            backends["FOREST_QUEUE_PREFIX"] = os.environ["FOREST_QUEUE_PREFIX"]
    return backends


def run_clip_bench(
    preset: str,
    frames: int,
    size: tuple[int, int],
    workers: list[int],
    echo: Callable[[str], None] = print,
    database_url: str | None = None,
    broker_url: str | None = None,
) -> dict[int, float]:
    """The wall time of one clip (mp4) of ``frames`` frames with each count of render
    workers, its frames split into chunks of ``FOREST_RENDER_CHUNK_FRAMES``, and each time's
    ratio to the first count's; answers workers -> seconds."""
    backends = _backends(database_url, broker_url)
    forest: dict[str, object] = {
        "preset": preset, "trees": 4, "seed": 3, "frames": 24, "fps": 24.0, "format": "usdc",
    }  # fmt: skip
    render: dict[str, object] = {
        "width": size[0], "height": size[1], "frames": frames, "clip": "mp4",
    }  # fmt: skip
    chunk = os.environ.get("FOREST_RENDER_CHUNK_FRAMES", "8")
    echo(
        f"clip: {frames} frames {size[0]}x{size[1]} mp4 of {preset} x 4 trees, chunks of "
        f"{chunk} frames, {os.cpu_count()} CPU(s)"
    )
    echo(f"{'workers':>8} {'seconds':>9} {'frames/s':>9} {'ratio':>7}")
    times: dict[int, float] = {}
    with tempfile.TemporaryDirectory(prefix="forest-bench-") as tmp:
        for w in workers:
            with embedded_server(Path(tmp) / f"clip{w}", w, backends) as served:
                seconds = clip_wall_time(served.url, forest, render)
            times[w] = seconds
            ratio = times[workers[0]] / seconds
            echo(f"{w:>8} {seconds:>9.2f} {frames / seconds:>9.2f} {ratio:>6.2f}x")
    return times


def run_service_bench(
    preset: str,
    concurrency: list[int],
    requests: int,
    workers: list[int],
    jobs: int,
    trees: int,
    echo: Callable[[str], None] = print,
    database_url: str | None = None,
    broker_url: str | None = None,
) -> None:
    backends = _backends(database_url, broker_url)
    broker = (broker_url or "sqla+sqlite").split(":", 1)[0]
    store = (database_url or "sqlite").split(":", 1)[0].split("+", 1)[0]
    with tempfile.TemporaryDirectory(prefix="forest-bench-") as tmp:
        echo(
            f"POST /v1/trees (preset {preset}, usdc), {requests} requests per level, "
            "embedded server"
        )
        # each tree is a job on the workers (the API waits for it): as many as the job runs'
        echo(f"{'clients':>8} {'p50 ms':>9} {'p99 ms':>9} {'req/s':>8} {'API MiB':>8}")
        with embedded_server(Path(tmp) / "api", max(workers)) as api:
            for c in concurrency:
                tree: dict[str, object] = {"preset": preset, "format": "usdc"}
                r = tree_latency(api.url, tree, c, max(requests, c))
                echo(
                    f"{c:>8} {r['p50_ms']:>9.1f} {r['p99_ms']:>9.1f} {r['rps']:>8.1f} "
                    f"{rss_mib(api.pid):>8.0f}"
                )
        echo(
            f"forest jobs: {jobs} jobs x {trees} trees (preset {preset}), "
            f"job store {store}, broker {broker}"
        )
        echo(f"{'workers':>8} {'seconds':>9} {'jobs/s':>8} {'trees/s':>9}")
        for w in workers:
            with embedded_server(Path(tmp) / f"jobs{w}", w, backends) as served:
                body: dict[str, object] = {"preset": preset, "trees": trees, "format": "usdc"}
                r = job_throughput(served.url, body, jobs)
                echo(
                    f"{w:>8} {r['seconds']:>9.2f} {r['jobs_per_s']:>8.2f} {r['trees_per_s']:>9.1f}"
                )
