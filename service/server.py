"""The HTTP server: uvicorn on its h11 protocol with a header timeout uvicorn lacks.

uvicorn closes a connection idle between requests (``timeout_keep_alive``), and the body is
timed by :class:`service.limits.BodyLimitMiddleware`, but nothing times the request line and
headers: a client that opens a connection and sends nothing, or trickles its headers a byte at
a time, holds a connection for ever (slowloris). :class:`SlowClientH11` answers 408 (or just
closes an idle connection) when a request's headers are not complete within
``header_timeout_s`` of the connection or of the first byte after a response.

``forest serve`` runs it through :func:`run` (one process) or :func:`run_processes`
(``--api-workers N``); the API containers through ``python -m service.server`` (:func:`main`:
several processes, the timeouts from ``FOREST_*``). Several processes share one Prometheus
``/metrics`` through a folder of metric files (:func:`shared_metrics_dir`).
"""

from __future__ import annotations

import asyncio
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from uvicorn.protocols.http.h11_impl import H11Protocol

from service.errors import problem_bytes

TIMEOUT_BODY = problem_bytes(
    408,
    "request headers not received in time",
    errors=[{"loc": ["header"], "msg": "request headers not received in time", "type": "timeout"}],
)
TIMEOUT_RESPONSE = (
    b"HTTP/1.1 408 Request Timeout\r\ncontent-type: application/problem+json\r\n"
    b"content-length: %d\r\nconnection: close\r\n\r\n%s" % (len(TIMEOUT_BODY), TIMEOUT_BODY)
)


class SlowClientH11(H11Protocol):
    header_timeout_s: float | None = None
    """Seconds a request's line and headers may take; None: ``FOREST_HEADER_TIMEOUT_S``."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        if self.header_timeout_s is None:
            from service.settings import ServiceSettings

            self.header_timeout_s = ServiceSettings().header_timeout_s
        self.header_timer: asyncio.TimerHandle | None = None
        self.partial = False  # bytes of a request whose headers are not complete yet

    def _between_requests(self) -> bool:
        return self.cycle is None or self.cycle.response_complete

    def _arm(self) -> None:
        if self.header_timer is None and self.header_timeout_s:
            self.header_timer = self.loop.call_later(self.header_timeout_s, self._expired)

    def _disarm(self) -> None:
        if self.header_timer is not None:
            self.header_timer.cancel()
            self.header_timer = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm()

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        if self._between_requests():
            self.partial = True
            self._arm()  # not re-armed by later bytes: the deadline runs from the first
        else:
            self.partial = False
            self._disarm()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def _expired(self) -> None:
        self.header_timer = None
        if self.transport.is_closing() or not self._between_requests():
            return
        if self.partial:
            self.transport.write(TIMEOUT_RESPONSE)
        self.transport.close()


def protocol(header_timeout_s: float) -> type[SlowClientH11]:
    """:class:`SlowClientH11` with this header timeout."""
    return type("SlowClientH11", (SlowClientH11,), {"header_timeout_s": header_timeout_s})


def run(app: Any, host: str, port: int, header_timeout_s: float, keep_alive_s: int) -> None:
    import uvicorn

    uvicorn.run(
        app,
        host=host,
        port=port,
        log_level="warning",
        http=protocol(header_timeout_s),
        timeout_keep_alive=keep_alive_s,
    )


def shared_metrics_dir(folder: Path) -> Path:
    """Make ``folder`` (emptied: samples of an earlier run's processes must not add up with
    this run's) the multiprocess metrics folder of the processes started from now on
    (``PROMETHEUS_MULTIPROC_DIR``, read by prometheus_client when it is imported)."""
    from service.metrics import MULTIPROC_ENV

    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    os.environ[MULTIPROC_ENV] = str(folder)
    return folder


def run_processes(host: str, port: int, workers: int, keep_alive_s: int, metrics_dir: Path) -> None:
    """The API in ``workers`` processes on one socket (uvicorn's supervisor restarts one that
    dies), each building the app from the environment (``service.app:app_from_env``), their
    request metrics summed through ``metrics_dir``."""
    import uvicorn

    shared_metrics_dir(metrics_dir)
    uvicorn.run(
        "service.app:app_from_env",
        factory=True,
        host=host,
        port=port,
        workers=workers,
        log_level="warning",
        # the class itself (it reads FOREST_HEADER_TIMEOUT_S): each process imports it
        http=SlowClientH11,
        timeout_keep_alive=keep_alive_s,
    )


def main(argv: list[str] | None = None) -> None:
    """``python -m service.server [--host H] [--port P] [--workers N]``: the API alone, as
    the cluster runs it (``service.app:app_from_env`` in ``N`` processes behind a proxy)."""
    import argparse

    import uvicorn

    from service.settings import ServiceSettings

    parser = argparse.ArgumentParser(prog="python -m service.server", description=main.__doc__)
    parser.add_argument("--host", default="0.0.0.0")
    parser.add_argument("--port", type=int, default=8000)
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args(argv)
    settings = ServiceSettings()
    from service.metrics import MULTIPROC_ENV

    if args.workers > 1 and not os.environ.get(MULTIPROC_ENV):
        # one /metrics for all processes; a deployment may name its own folder
        shared_metrics_dir(Path(tempfile.mkdtemp(prefix="forest-metrics-")))
    uvicorn.run(
        "service.app:app_from_env",
        factory=True,
        host=args.host,
        port=args.port,
        workers=args.workers,
        proxy_headers=True,
        # the class itself (it reads FOREST_HEADER_TIMEOUT_S): each process imports it
        http=SlowClientH11,
        timeout_keep_alive=settings.keep_alive_s,
    )


if __name__ == "__main__":
    main()
