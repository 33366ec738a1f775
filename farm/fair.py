"""The fair window: a tiled forest's tiles reach the broker a few at a time, fairly across
tenants, so no request can fill the queue ahead of everyone else's work.

A tiled forest job writes its tile rows held (queued, no ``enqueued_at``: :data:`farm.store.HELD`).
:func:`pump` sends held tiles while fewer than ``max_tiles_in_flight`` tiles are in flight (sent
and not finished), each time from the tenant with the fewest tiles in flight, none past
``max_tenant_tiles_in_flight``; within a tenant the job of highest ``priority``, then the oldest.
It runs whenever a tile ends (in the worker that ran it) and at each poll of a tiled forest job
(:mod:`farm.tiles`), so capacity refills as it frees. The broker therefore never holds more than
the window: another tenant's job, sent at once, waits behind at most about one tile. The state
is the job table's (one pump at a time holds a lock of the database while it counts and takes);
the broker stays Celery's (a plain send per tile).
"""

from __future__ import annotations

import logging
from collections import Counter

from farm.dispatch import Dispatcher
from farm.settings import FarmSettings
from farm.store import JobStore

log = logging.getLogger(__name__)
TILE_KIND = "forest_tile"


def pump(store: JobStore, dispatcher: Dispatcher, settings: FarmSettings) -> int:
    """Send held tiles while the window has room; how many were sent. One pump at a time
    counts and takes (:meth:`JobStore.exclusive`), so concurrent pumps (every worker runs
    one) neither send a tile twice nor overshoot the window; the messages go out after."""
    taken: list[str] = []
    with store.exclusive() as s:
        backlog = store.backlog(s)
        flying = store.in_flight([b.id for b in backlog], s)
        tenants: Counter[str] = Counter()
        for b in backlog:
            tenants[b.tenant] += flying.get(b.id, 0)
        total = sum(tenants.values())
        drained: set[str] = set()
        while total < settings.max_tiles_in_flight:
            ready = [
                b
                for b in backlog
                if b.id not in drained and tenants[b.tenant] < settings.max_tenant_tiles_in_flight
            ]
            if not ready:
                break
            # the tenant with least in flight; then its most urgent, oldest job
            job = min(ready, key=lambda b: (tenants[b.tenant], -b.priority, b.created_at, b.id))
            tile = store.take_held(s, job.id)
            if tile is None:
                drained.add(job.id)
                continue
            taken.append(tile)
            tenants[job.tenant] += 1
            total += 1
    for k, tile in enumerate(taken):
        try:
            dispatcher.send(tile, TILE_KIND)
        except Exception:
            for unsent in taken[k:]:
                store.hold_again(unsent)  # the next pump tries again
            raise
    return len(taken)


def pump_quietly(store: JobStore, dispatcher: Dispatcher, settings: FarmSettings) -> None:
    """:func:`pump` where a failure must not fail the caller (a tile that just ended): the
    next tile's end or the forest job's next poll pumps again."""
    try:
        pump(store, dispatcher, settings)
    except Exception:
        log.exception("the fair window could not send tiles")
