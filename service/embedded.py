"""``forest serve``: the API (uvicorn) plus local worker processes, supervised (a worker that
dies is started again). With no URLs set, the job store, the broker (kombu's SQLite
transport) and the artifacts all live in the data folder: nothing to install or run."""

from __future__ import annotations

import logging
import subprocess
import sys
import threading
import time
from pathlib import Path

from service.settings import ServiceSettings

log = logging.getLogger(__name__)


def _die_with_parent() -> None:
    """Linux: a worker gets SIGKILL when ``forest serve`` dies, so none is left orphaned."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6").prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


class Workers:
    """Keeps ``n`` ``python -m worker`` processes alive; pid files in ``<data>/run/``."""

    def __init__(
        self, settings: ServiceSettings, n: int, queues: str = "default,render,gpu,cpu"
    ) -> None:
        self.settings, self.n, self.queues = settings, n, queues
        self.procs: list[subprocess.Popen[bytes] | None] = [None] * n
        self.run_dir = settings.data_dir.resolve() / "run"
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._watch, name="forest-workers", daemon=True)

    def _spawn(self, i: int) -> None:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        log_file = open(self.run_dir / f"worker-{i}.log", "ab")  # noqa: SIM115
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "worker",
                "-Q",
                self.queues,
                "--name",
                f"w{i}-{time.time_ns()}@%h",
            ],
            stdout=log_file,
            stderr=subprocess.STDOUT,
            preexec_fn=_die_with_parent if sys.platform == "linux" else None,
        )
        log_file.close()
        self.procs[i] = proc
        (self.run_dir / f"worker-{i}.pid").write_text(str(proc.pid))

    def start(self) -> None:
        for i in range(self.n):
            self._spawn(i)
        self.thread.start()

    def _watch(self) -> None:
        while not self.stopping.wait(0.5):
            for i, proc in enumerate(self.procs):
                if proc is not None and proc.poll() is not None and not self.stopping.is_set():
                    log.warning("worker %d exited with %s; starting another", i, proc.returncode)
                    self._spawn(i)

    def stop(self) -> None:
        self.stopping.set()
        for proc in self.procs:
            if proc is not None and proc.poll() is None:
                proc.terminate()
        for proc in self.procs:
            if proc is not None:
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()


def serve(
    settings: ServiceSettings, host: str, port: int, workers: int, api_workers: int = 1
) -> None:
    """The API in ``api_workers`` processes (one: in this process) and ``workers`` job
    workers. Several API processes build their app from the environment, so ``settings``
    must be what ``ServiceSettings()`` reads there; their metrics meet in
    ``<data>/run/metrics``, emptied at start."""
    from farm.db import migrate
    from service.server import run as run_server
    from service.server import run_processes

    Path(settings.data_dir).mkdir(parents=True, exist_ok=True)
    migrate(settings.db_url)  # once, before workers and API race to create the table
    pool = Workers(settings, workers)
    if workers:
        pool.start()
    try:
        if api_workers > 1:
            metrics_dir = settings.data_dir.resolve() / "run" / "metrics"
            run_processes(host, port, api_workers, settings.keep_alive_s, metrics_dir)
        else:
            from service.app import create_app

            run_server(
                create_app(settings), host, port, settings.header_timeout_s, settings.keep_alive_s
            )
    finally:
        pool.stop()
