"""Webhooks: a job that names a ``webhook`` URL has it called once the job has ended: one
POST of JSON (the job's id, kind, state, error, times, artifact names, result), signed with
HMAC-SHA256 under ``webhook_secret``.

Only hosts of ``webhook_hosts`` may be called (checked when the job is submitted and again
before each call: the farm calls no address a client picks, e.g. an internal service), no
redirect is followed, and each call is limited to ``webhook_timeout_s``. A call answered
other than 2xx (or not at all) is tried again after 1, 2, 4, ... s (at most 5 minutes
apart), up to ``webhook_attempts`` calls. Deliveries are made by a thread beside the reaper
of the API and of every worker (:class:`Deliveries`): each call is claimed in the job row
first (its next try set a while ahead), so two of them never make the same call; one that
dies mid-call leaves the claim to run out and the call is made again (a receiver may see one
call twice: the ``X-Forest-Delivery`` header names the job and attempt, to tell)."""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import threading
import time
import urllib.error
import urllib.request
from datetime import timedelta
from typing import Any
from urllib.parse import urlsplit

from sqlalchemy import select, update

from farm import joblog
from farm.db import JobRow, utcnow
from farm.settings import FarmSettings
from farm.store import FINISHED, JobStore

log = logging.getLogger(__name__)
BATCH = 20  # calls per reaper round at most
MAX_BACKOFF_S = 300.0
SIGNATURE = "X-Forest-Signature"


def host_allowed(host: str, patterns: str) -> bool:
    """``host`` is one of ``patterns`` (comma separated; ``*.example.com``: its subdomains)."""
    host = host.lower().rstrip(".")
    for raw in patterns.split(","):
        pattern = raw.strip().lower().rstrip(".")
        if not pattern:
            continue
        if pattern.startswith("*."):
            if host.endswith(pattern[1:]) and len(host) > len(pattern) - 1:
                return True
        elif host == pattern:
            return True
    return False


def refusal(url: str, settings: FarmSettings) -> str | None:
    """Why ``url`` may not be a job's webhook here; None when it may."""
    if not settings.webhook_secret:
        return "webhooks are off on this server (FOREST_WEBHOOK_SECRET is not set)"
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        return "must be an http or https URL with a host"
    if parts.username or parts.password:
        return "must not carry a user name or password"
    if not host_allowed(parts.hostname, settings.webhook_hosts):
        return f"host {parts.hostname!r} is not one of FOREST_WEBHOOK_HOSTS"
    return None


def sign(secret: str, timestamp: str, body: bytes) -> str:
    """``sha256=<hex>`` of ``<timestamp>.<body>`` (the timestamp signed too: a receiver can
    refuse an old call replayed)."""
    mac = hmac.new(secret.encode(), timestamp.encode() + b"." + body, hashlib.sha256)
    return f"sha256={mac.hexdigest()}"


def payload(row: JobRow) -> dict[str, Any]:
    def at(t: Any) -> str | None:
        return t.isoformat() + "Z" if t is not None else None

    return {
        "event": "job.ended",
        "job": {
            "id": row.id, "kind": row.kind, "state": row.state, "attempts": row.attempts,
            "error": row.error, "created_at": at(row.created_at),
            "finished_at": at(row.finished_at), "artifacts": list(row.artifacts or []),
            "result": row.result,
        },
    }  # fmt: skip


class _NoRedirects(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args: Any, **kwargs: Any) -> None:
        return None  # a 3xx is the answer, not a hop to a host nobody allowed


_opener = urllib.request.build_opener(_NoRedirects)


def call(url: str, body: bytes, headers: dict[str, str], timeout_s: float) -> str | None:
    """POST ``body``; None when answered 2xx, else what went wrong."""
    req = urllib.request.Request(url, data=body, headers=headers, method="POST")
    try:
        with _opener.open(req, timeout=timeout_s) as res:
            status = int(res.status)
    except urllib.error.HTTPError as exc:
        status = exc.code
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        return f"no answer: {type(exc).__name__}: {reason}"[:500]
    return None if 200 <= status < 300 else f"answered HTTP {status}"


def _claim(store: JobStore, row: JobRow, lease_s: float) -> bool:
    now = utcnow()
    with store.session() as s, s.begin():
        res = s.execute(
            update(JobRow)
            .where(
                JobRow.id == row.id,
                JobRow.webhook_pending.is_(True),
                JobRow.webhook_attempts == row.webhook_attempts,
            )
            .values(
                webhook_attempts=row.webhook_attempts + 1,
                webhook_next_at=now + timedelta(seconds=lease_s),
            )
            .execution_options(synchronize_session=False)
        )
    return res.rowcount == 1  # type: ignore[attr-defined, no-any-return]


def _settle(
    store: JobStore, row: JobRow, error: str | None, settings: FarmSettings, final: bool = False
) -> None:
    attempt = row.webhook_attempts + 1
    now = utcnow()
    if error is None:
        values: dict[str, Any] = {"webhook_pending": False, "webhook_done_at": now}
        note = ("info", f"webhook called (attempt {attempt})")
    elif final:
        values = {"webhook_pending": False}
        note = ("error", f"webhook given up: {error}")
    elif attempt >= settings.webhook_attempts:
        values = {"webhook_pending": False}
        note = ("error", f"webhook given up after {attempt} attempt(s): {error}")
    else:
        wait = min(MAX_BACKOFF_S, 2.0 ** (attempt - 1))
        values = {"webhook_next_at": now + timedelta(seconds=wait)}
        note = ("warning", f"webhook attempt {attempt} failed, again in {wait:g} s: {error}")
    with store.session() as s, s.begin():
        s.execute(
            update(JobRow)
            .where(JobRow.id == row.id)
            .values(webhook_error=error, **values)
            .execution_options(synchronize_session=False)
        )
    try:
        joblog.append(store, row.id, row.attempts, [joblog.Line(*note)], settings.job_log_lines)
    except Exception:  # the delivery's state is recorded; its log line is a courtesy
        log.exception("writing the log of job %s failed", row.id)


def deliver_due(store: JobStore, settings: FarmSettings) -> int:
    """Make the webhook calls that are due (jobs ended, not delivered, their next try come);
    how many were made."""
    now = utcnow()
    with store.session() as s:
        due = list(
            s.scalars(
                select(JobRow)
                .where(
                    JobRow.webhook_pending.is_(True),
                    JobRow.state.in_(FINISHED),
                    (JobRow.webhook_next_at.is_(None)) | (JobRow.webhook_next_at <= now),
                )
                .order_by(JobRow.finished_at)
                .limit(BATCH)
            )
        )
    made = 0
    for row in due:
        # the call's own time and then some: another reaper does not take it meanwhile
        if not _claim(store, row, settings.webhook_timeout_s * 2 + 5):
            continue
        url = row.webhook_url or ""
        error = refusal(url, settings)
        final = error is not None
        if error is None:
            body = json.dumps(payload(row), separators=(",", ":")).encode()
            stamp = str(int(time.time()))
            headers = {
                "Content-Type": "application/json",
                "User-Agent": "interlocking-forest-webhook",
                "X-Forest-Timestamp": stamp,
                "X-Forest-Delivery": f"{row.id}.{row.webhook_attempts + 1}",
                SIGNATURE: sign(settings.webhook_secret, stamp, body),
            }
            error = call(url, body, headers, settings.webhook_timeout_s)
        else:  # the settings changed since it was accepted: no call, and no retry helps
            error = f"not called: {error}"
        _settle(store, row, error, settings, final)
        made += 1
    return made


class Deliveries(threading.Thread):
    """Calls due webhooks every ``interval_s``, beside the reaper (whose rounds a slow
    receiver must not hold up)."""

    def __init__(self, store: JobStore, settings: FarmSettings, interval_s: float) -> None:
        super().__init__(name="forest-webhooks", daemon=True)
        self.store, self.settings, self.interval_s = store, settings, interval_s
        self.stopped = threading.Event()

    def run(self) -> None:
        while not self.stopped.wait(self.interval_s):
            try:
                deliver_due(self.store, self.settings)
            except Exception:  # the store is away: the calls are made in a later round
                log.exception("webhook deliveries failed")

    def stop(self) -> None:
        self.stopped.set()
