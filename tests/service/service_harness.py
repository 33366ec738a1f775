"""Harness of the service tests: real servers: ``forest serve`` in a subprocess, on the embedded
default (SQLite job store and broker in a temporary data folder) and on two cluster backends
(PostgreSQL in a database of its own, with RabbitMQ queue names or Redis keys of its own), all
dropped at the end. A server that is not running fails the test with how to start it; `.ci/run`
starts them."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

PG = ("127.0.0.1", 5432)
RABBIT = ("127.0.0.1", 5672)
RABBIT_URL = "amqp://guest:guest@127.0.0.1:5672//"
REDIS = ("127.0.0.1", 6379)
REDIS_URL = "redis://127.0.0.1:6379/0"  # each run's keys carry a prefix of its own
START_HINT = {
    "PostgreSQL": "pg_ctlcluster --skip-systemctl-redirect $(ls /etc/postgresql) main start",
    "RabbitMQ": "rabbitmq-server -detached",
    "Redis": "redis-server --daemonize yes --bind 127.0.0.1 -::1 --port 6379 --save '' "
    "--appendonly no",
}
# short leases so a killed worker's job comes back within seconds
FAST = {
    "FOREST_LEASE_S": "5",
    "FOREST_HEARTBEAT_S": "0.5",
    "FOREST_REAPER_INTERVAL_S": "0.5",
    "FOREST_REQUEUE_AFTER_S": "15",
    "FOREST_RETRY_DELAY_S": "0.2",
    "FOREST_RATE_LIMIT": "",  # tests that mean to be limited set their own
}


def require_server(name: str, addr: tuple[str, int]) -> None:
    try:
        socket.create_connection(addr, timeout=2).close()
    except OSError as exc:
        pytest.fail(
            f"{name} at {addr[0]}:{addr[1]} is unreachable ({exc}); these tests need it "
            f"running: {START_HINT[name]} (.ci/run starts it)",
            pytrace=False,
        )


@contextlib.contextmanager
def pg_database(tag: str) -> Iterator[str]:
    """A PostgreSQL database of its own; its SQLAlchemy URL."""
    import psycopg

    db = f"forest_test_{tag}"
    admin = "host=127.0.0.1 port=5432 user=postgres dbname=postgres"  # every cluster has it
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{db}"')
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:5432/{db}"
    finally:
        with psycopg.connect(admin, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{db}" WITH (FORCE)')


def delete_rabbit_queues(prefix: str) -> None:
    from kombu import Connection

    with Connection(RABBIT_URL) as conn:
        channel = conn.channel()
        for q in ("default", "render", "gpu", "cpu"):
            try:
                channel.queue_delete(prefix + q)
                channel.exchange_delete(prefix + q)
            except Exception:  # never declared: nothing to delete
                channel = conn.channel()


def delete_redis_keys(prefix: str) -> int:
    """Every key of the run (queues, unacked hash, bindings: all carry the prefix)."""
    import redis

    client = redis.Redis.from_url(REDIS_URL)
    try:
        keys = list(client.scan_iter(match=f"{prefix}*", count=1000))
        if keys:
            client.delete(*keys)
        return len(keys)
    finally:
        client.close()


@contextlib.contextmanager
def own_backend(backend: dict[str, str]) -> Iterator[dict[str, str]]:
    """``backend`` with a PostgreSQL database and queue names (RabbitMQ) or Redis keys of
    their own, all dropped at the end; the embedded backend ({}) as it is."""
    broker = backend.get("FOREST_BROKER_URL")
    if broker is None:
        yield backend
        return
    tag = uuid.uuid4().hex[:12]
    prefix = f"forest-test-{tag}."
    with pg_database(tag) as db_url:
        try:
            yield backend | {"FOREST_DATABASE_URL": db_url, "FOREST_QUEUE_PREFIX": prefix}
        finally:
            if broker.startswith("amqp"):
                delete_rabbit_queues(prefix)
            else:
                delete_redis_keys(prefix)


def redis_unacked(prefix: str) -> int:
    """How many delivered messages no worker has acknowledged (Redis broker)."""
    import redis

    client = redis.Redis.from_url(REDIS_URL)
    try:
        return int(client.hlen(f"{prefix}unacked"))
    finally:
        client.close()


def redis_pending(prefix: str) -> int:
    """Messages of the run not yet done with: waiting in a queue (a list) or unacknowledged."""
    import redis

    client = redis.Redis.from_url(REDIS_URL)
    try:
        queued = sum(
            int(client.llen(key))
            for key in client.scan_iter(match=f"{prefix}*", count=1000, _type="list")
        )
        return queued + int(client.hlen(f"{prefix}unacked"))
    finally:
        client.close()


def redis_redeliver_now(prefix: str) -> int:
    """What Redis does once the visibility timeout is past: every unacknowledged message of the
    run goes back to its queue. Returns how many went back.

    kombu's ``restore_visible`` silently does nothing while another client holds the restore
    mutex (a live worker's periodic sweep, or one killed mid-sweep: then for five minutes), so
    this restores tag by tag, which is one WATCH transaction each and needs no mutex."""
    from kombu import Connection

    with Connection(REDIS_URL, transport_options={"global_keyprefix": prefix}) as conn:
        qos = conn.default_channel.qos
        with conn.default_channel.conn_or_acquire() as client:
            tags = client.zrange(qos.unacked_index_key, 0, -1)
            for tag in tags:
                qos.restore_by_tag(tag, client)
        return len(tags)


def _die_with_parent() -> None:
    """Linux: a worker gets SIGKILL when the thread that started it ends (the test's)."""
    with contextlib.suppress(OSError, AttributeError):
        import ctypes

        ctypes.CDLL("libc.so.6").prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


class HookedWorkers:
    """``n`` job workers with a test's hooks in their kinds (:mod:`job_hooks`), kept alive as
    ``forest serve`` keeps its own (one that dies is started again); pid files and logs in
    ``<data>/run/`` as ``forest serve`` writes them."""

    def __init__(
        self,
        run_dir: Path,
        n: int,
        env: dict[str, str],
        hooks: dict[str, float],
        queues: str = "default,render,gpu,cpu",
    ) -> None:
        import job_hooks

        here = str(Path(__file__).parent)
        path = os.pathsep.join(p for p in (here, env.get("PYTHONPATH", "")) if p)
        self.env = env | {"PYTHONPATH": path, job_hooks.HOOKS_ENV: json.dumps(hooks)}
        self.run_dir, self.n, self.queues = run_dir, n, queues
        self.procs: list[subprocess.Popen[bytes]] = []
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._watch, daemon=True)

    def _spawn(self, i: int) -> subprocess.Popen[bytes]:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        with open(self.run_dir / f"worker-{i}.log", "ab") as log:
            proc = subprocess.Popen(
                [sys.executable, "-c", "import job_hooks; job_hooks.main()",
                 "-Q", self.queues, "--name", f"w{i}-{time.time_ns()}@%h"],
                env=self.env, stdout=log, stderr=subprocess.STDOUT,
                preexec_fn=_die_with_parent,
            )  # fmt: skip
        (self.run_dir / f"worker-{i}.pid").write_text(str(proc.pid))
        return proc

    def start(self) -> HookedWorkers:
        self.procs = [self._spawn(i) for i in range(self.n)]
        self.thread.start()
        return self

    def _watch(self) -> None:
        while not self.stopping.wait(0.5):
            for i, proc in enumerate(self.procs):
                if proc.poll() is not None and not self.stopping.is_set():
                    self.procs[i] = self._spawn(i)

    def stop(self) -> None:
        self.stopping.set()
        self.thread.join()
        for proc in self.procs:
            if proc.poll() is None:
                proc.terminate()
        for proc in self.procs:
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Server:
    """``forest serve`` in a subprocess; ``stop()`` leaves no process behind. With ``hooks``
    (:mod:`job_hooks`) its workers are the test's own, their kinds with those hooks."""

    def __init__(
        self,
        data: Path,
        env: dict[str, str],
        workers: int = 2,
        api_workers: int = 1,
        hooks: dict[str, float] | None = None,
        queues: str | None = None,
    ) -> None:
        self.data, self.workers, self.api_workers = data, workers, api_workers
        # workers of other queues than ``forest serve``'s own (all): started as hooked ones
        self.hooks = {} if hooks is None and queues is not None else hooks
        self.queues = queues or "default,render,gpu,cpu"
        self.pool: HookedWorkers | None = None
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("FOREST_")}
        self.env |= {"FOREST_DATA_DIR": str(data)} | FAST | env
        self.proc: subprocess.Popen[bytes] | None = None
        self.port = 0
        self.headers: dict[str, str] = {}  # e.g. an X-API-Key the helpers send

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> Server:
        try:
            return self._start()
        except BaseException:  # pytest.fail included: leave no process behind
            self.stop()
            raise

    def _start(self) -> Server:
        self.data.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        if self.hooks is not None:
            # as ``forest serve`` does for its own: the table first (once: the workers and the
            # API would race to make it), then the workers, starting beside the API
            from farm.db import migrate
            from farm.settings import FarmSettings

            db = self.env.get("FOREST_DATABASE_URL")
            migrate(FarmSettings(data_dir=self.data, database_url=db).db_url)
            self.pool = HookedWorkers(
                self.data / "run", self.workers, self.env, self.hooks, self.queues
            )
            self.pool.start()
        log = open(self.data / "serve.log", "ab")  # noqa: SIM115
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "cli",
                "serve",
                "--port",
                str(self.port),
                "--workers",
                str(self.workers if self.hooks is None else 0),
                "--api-workers",
                str(self.api_workers),
            ],
            env=self.env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        log.close()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                pytest.fail(f"forest serve exited: {self.log()}")
            try:
                if httpx.get(f"{self.url}/readyz", timeout=2).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        pytest.fail(f"forest serve did not become ready: {self.log()}")

    def log(self) -> str:
        text = (self.data / "serve.log").read_text(errors="replace")
        for f in sorted((self.data / "run").glob("worker-*.log")):
            text += f"\n--- {f.name}\n" + f.read_text(errors="replace")[-3000:]
        return text[-8000:]

    def worker_pids(self) -> list[int]:
        return [int(p.read_text()) for p in sorted((self.data / "run").glob("worker-*.pid"))]

    def stop(self) -> None:
        if self.pool is not None:
            self.pool.stop()
            self.pool = None
        if self.proc is None:
            return
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for pid in self.worker_pids():  # the workers are ours: make sure none outlives us
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        self.proc = None

    # -- client helpers ---------------------------------------------------------------------

    def post(self, path: str, body: dict[str, Any], **kw: Any) -> httpx.Response:
        headers = self.headers | kw.pop("headers", {})
        return httpx.post(f"{self.url}{path}", json=body, timeout=60, headers=headers, **kw)

    def get(self, path: str, headers: dict[str, str] | None = None) -> httpx.Response:
        return httpx.get(f"{self.url}{path}", timeout=30, headers=self.headers | (headers or {}))

    def wait(
        self,
        job_id: str,
        states: tuple[str, ...] = ("completed", "failed", "canceled"),
        timeout: float = 60,
    ) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        job: dict[str, Any] = {}
        while time.monotonic() < deadline:
            job = self.get(f"/v1/jobs/{job_id}").json()
            if job["state"] in states:
                return job
            time.sleep(0.1)
        pytest.fail(f"job {job_id} still {job.get('state')} after {timeout}s: {job}\n{self.log()}")


def served(
    data: Path, env: dict[str, str], hooks: dict[str, float] | None = None
) -> Iterator[Server]:
    """A started server for a fixture (``yield from served(...)``), stopped afterwards."""
    server = Server(data, env, hooks=hooks).start()
    try:
        yield server
    finally:
        server.stop()


def reference_scene(tmp: Path, body: dict[str, Any], stem: str = "scene") -> bytes:
    """The library's own output for a forest or tree request body (a .usdz names its inner
    layer by stem)."""
    from farm.requests import options_from_request
    from forest.export import single_file
    from forest.growth.generate import generate_forest
    from forest.growth.presets import load_preset
    from forest.usd.scene import write_scene
    from schemas.jobs import ForestRequest, TreeRequest

    # the request as the service parses and maps it, so the reference cannot drift from it
    req = (ForestRequest if "trees" in body else TreeRequest).model_validate(body)
    assert req.preset is not None
    forest = generate_forest(load_preset(req.preset), req.seed, options_from_request(req))
    (tmp / "ref").mkdir(exist_ok=True)
    path = tmp / "ref" / f"{stem}.{body['format']}"
    # one file answers: pictures only where it carries them (forest.export.single_file)
    textures = single_file(path)
    return write_scene(forest, path, skinned=req.skinned, textures=textures).read_bytes()


class Proxy:
    """A TCP proxy to a server (PostgreSQL, RabbitMQ, Redis) that a test can cut: the server
    goes away for whoever reaches it through the proxy (every connection closed, each new one
    closed as it comes) until :meth:`restore`. The proxy keeps its port bound throughout, so
    nothing else (another test's server or proxy) can take it while the server is away."""

    def __init__(self, target: tuple[str, int]) -> None:
        self.target = target
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.conns: list[socket.socket] = []
        self.open = True
        # a connection being set up as the test cuts is either closed by the cut or refused
        self.lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.sock.accept()
            except OSError:  # closed
                return
            with self.lock:
                if not self.open:
                    client.close()
                    continue
                try:
                    upstream = socket.create_connection(self.target)
                except OSError:
                    client.close()
                    continue
                self.conns += [client, upstream]
            for a, b in ((client, upstream), (upstream, client)):
                threading.Thread(target=self._pipe, args=(a, b), daemon=True).start()

    @staticmethod
    def _pipe(a: socket.socket, b: socket.socket) -> None:
        try:
            while data := a.recv(65536):
                b.sendall(data)
        except OSError:
            pass
        finally:
            for s in (a, b):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)

    def cut(self) -> None:
        """The server goes away: open connections closed, new ones closed as they come."""
        with self.lock:
            self.open = False
            for c in self.conns:
                # a pipe thread may have shut it down already: close it whatever shutdown says
                with contextlib.suppress(OSError):
                    c.shutdown(socket.SHUT_RDWR)
                c.close()
            self.conns.clear()

    def restore(self) -> None:
        """The server is back for new connections."""
        with self.lock:
            self.open = True

    def close(self) -> None:
        self.cut()
        with contextlib.suppress(OSError):  # wakes the thread blocked in accept
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()


def tree_file(server: Server, body: dict[str, object]) -> httpx.Response:
    """The tree's file: answered at once, or (202) the job's artifact once it is done."""
    r = server.post("/v1/trees", body)
    if r.status_code == 202:  # a slow machine: the job was not done within the wait
        job = server.wait(r.json()["id"], timeout=300)
        assert job["state"] == "completed", job
        r = server.get(job["artifacts"][0]["url"])
    assert r.status_code == 200, r.text
    return r


def forest_then_render(
    server: Server, body: dict[str, Any], size: tuple[int, int] = (64, 48)
) -> tuple[dict[str, Any], dict[str, Any]]:
    """A forest job of ``body``, then a render job of it, both completed; both jobs and the
    render's metrics (``job["metrics"]``)."""
    r = server.post("/v1/forests", body)
    assert r.status_code == 202, r.text
    forest = server.wait(r.json()["id"], timeout=300)
    assert forest["state"] == "completed", forest
    r = server.post(
        "/v1/renders", {"forest_job": forest["id"], "width": size[0], "height": size[1]}
    )
    assert r.status_code == 202, r.text
    job = server.wait(r.json()["id"], timeout=300)
    assert job["state"] == "completed", job
    url = next(a["url"] for a in job["artifacts"] if a["name"] == "metrics.json")
    return forest, job | {"metrics": server.get(url).json()}
