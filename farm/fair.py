"""The fair window: every job reaches the broker a few at a time, fairly across tenants, so no
tenant's backlog can fill the queue ahead of everyone else's work.

A job is written held (queued, no ``enqueued_at``: :data:`farm.store.HELD`), and so are a tiled
forest's tile rows. :func:`pump` sends held jobs and tiles while fewer than
``max_tiles_in_flight`` are in flight (sent and not finished, all tenants together), each time
from the tenant with the fewest in flight, none past ``max_tenant_tiles_in_flight``; within a
tenant its highest ``priority`` first, then the oldest. A tiled forest counts until its tiles
are written, then only its tiles do (so a tenant's forests cannot take its whole share while
they wait on their own tiles). It runs when a job is submitted (the API), whenever a job or
tile ends (in the worker that ran it), at each poll of a tiled forest (:mod:`farm.tiles`) and
at each reaper round (a pump missed by a crash), so capacity refills as it frees. The broker
therefore never holds more than the window: another tenant's job waits behind at most about
one task per worker. The state is the job table's (one pump at a time holds a lock of the
database while it counts and takes); the broker stays Celery's (a plain send per job).
"""

from __future__ import annotations

import logging
from collections import Counter

from farm.dispatch import Dispatcher
from farm.graph import settle
from farm.settings import FarmSettings
from farm.store import CHUNK_KIND, TILE_KIND, JobStore

__all__ = ["CHUNK_KIND", "TILE_KIND", "pump", "pump_quietly", "render_pool"]

log = logging.getLogger(__name__)


def pump(store: JobStore, dispatcher: Dispatcher, settings: FarmSettings) -> int:
    """Send held jobs and tiles while the window has room; how many were sent. One pump at a time
    counts and takes (:meth:`JobStore.exclusive`), so concurrent pumps (every worker runs
    one) neither send a job twice nor overshoot the window; the messages go out after. If a
    send fails, what was not sent is held again and the error raised."""
    taken: list[tuple[str, str]] = []
    with store.exclusive() as s:
        settle(s)  # jobs whose jobs have ended join the window (or fail, or cancel)
        waiting = store.waiting(s)
        flying: Counter[str] = Counter(store.in_flight(s))
        total = sum(flying.values())
        while total < settings.max_tiles_in_flight:
            ready = [t for t in waiting if flying[t] < settings.max_tenant_tiles_in_flight]
            if not ready:
                break
            # the tenant with least in flight (the longest waiting on a tie)
            tenant = min(ready, key=lambda t: (flying[t], waiting[t], t))
            got = store.take_next(s, tenant)
            if got is None:
                del waiting[tenant]
                continue
            taken.append(got)
            flying[tenant] += 1
            total += 1
    for k, (job_id, kind) in enumerate(taken):
        try:
            dispatcher.send(job_id, kind, pool=render_pool(store, job_id, kind))
        except Exception:
            for unsent, _ in taken[k:]:
                store.hold_again(unsent)  # the next pump tries again
            raise
    return len(taken)


def render_pool(store: JobStore, job_id: str, kind: str) -> str | None:
    """A render job's pool (its queue), read only for renders and their chunks (a chunk row
    carries its render's pool): other kinds have one queue."""
    if kind not in ("render", CHUNK_KIND):
        return None
    row = store.get(job_id)
    return None if row is None else (row.params or {}).get("pool")


def pump_quietly(store: JobStore, dispatcher: Dispatcher, settings: FarmSettings) -> None:
    """:func:`pump` where a failure must not fail the caller (a job that just ended, a reaper
    round): the next job's end, tiled forest's poll or reaper round pumps again."""
    try:
        pump(store, dispatcher, settings)
    except Exception:
        log.exception("the fair window could not send jobs")
