"""A worker's liveness probe: ``python -m worker.probe`` (or ``forest worker --check``) exits 0
when the worker on this host wrote its row in the worker registry (:mod:`farm.workers`)
within ``worker_timeout_s``, and 1 when that row is stale, marked stopped, or not there yet.

Run as an exec probe in the worker's container (Kubernetes ``livenessProbe``, with a
``startupProbe`` running the same command for the start, which registers after the heavy
imports and migrations): the host is the pod's name (the container's hostname in Compose), so
the newest row of this host is this container's worker process. It is one indexed query on the
job store, with no heavy import (no Celery, no pxr).

A job store it cannot reach is not this worker's fault, and restarting every worker would not
bring it back: that exits 0 with a line saying so (``--strict``: 1). The worker's heartbeat
thread writes its row again once the store answers.
"""

from __future__ import annotations

import argparse
import socket
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy import Engine, create_engine, select
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.pool import NullPool

from farm.db import WorkerRow, engine_for, utcnow

OK, STALE = 0, 1
CONNECT_TIMEOUT_S = 5
"""A database server that does not answer a connection within this is unreachable (under a
probe's usual 10 s limit, which would otherwise count a hung connect as this worker's fault)."""


def _engine(url: str) -> Engine:
    if url.startswith("postgresql"):  # one connection, given up after CONNECT_TIMEOUT_S
        return create_engine(
            url, poolclass=NullPool, connect_args={"connect_timeout": CONNECT_TIMEOUT_S}
        )
    return engine_for(url)  # SQLite: a file, with the store's busy timeout


@dataclass(frozen=True)
class Verdict:
    code: int
    line: str


def check(
    url: str, host: str, timeout_s: float, strict: bool = False, now: datetime | None = None
) -> Verdict:
    """The verdict on the newest registry row of ``host`` in the job store at ``url``."""
    try:
        with _engine(url).connect() as conn:
            row = conn.execute(
                select(WorkerRow.id, WorkerRow.last_seen, WorkerRow.stopped_at)
                .where(WorkerRow.host == host)
                .order_by(WorkerRow.started_at.desc())
                .limit(1)
            ).first()
    except SQLAlchemyError as exc:
        reason = type(exc).__name__
        return Verdict(STALE if strict else OK, f"job store unreachable ({reason}): not judged")
    if row is None:
        return Verdict(STALE, f"no worker of host {host} in the registry (not registered yet?)")
    if row.stopped_at is not None:
        return Verdict(STALE, f"worker {row.id} stopped at {row.stopped_at:%Y-%m-%dT%H:%M:%S}Z")
    age = ((now or utcnow()) - row.last_seen).total_seconds()
    if age > timeout_s:
        return Verdict(STALE, f"worker {row.id} last seen {age:.0f} s ago (> {timeout_s:g} s)")
    return Verdict(OK, f"worker {row.id} last seen {age:.1f} s ago")


def main(argv: Sequence[str] | None = None) -> int:
    from farm.settings import get_settings

    settings = get_settings()
    parser = argparse.ArgumentParser(
        prog="python -m worker.probe",
        description="Exit 1 when this host's worker has not written its registry row within "
        "FOREST_WORKER_TIMEOUT_S (a liveness probe).",
    )
    parser.add_argument("--host", default=socket.gethostname(), help="default: this host")
    parser.add_argument(
        "--timeout-s", type=float, default=settings.worker_timeout_s, help="default: "
        "FOREST_WORKER_TIMEOUT_S"
    )  # fmt: skip
    parser.add_argument(
        "--strict", action="store_true", help="an unreachable job store fails the probe too"
    )
    args = parser.parse_args(argv)
    verdict = check(settings.db_url, args.host, args.timeout_s, args.strict)
    print(verdict.line, file=sys.stdout if verdict.code == OK else sys.stderr)
    return verdict.code


if __name__ == "__main__":
    sys.exit(main())
