"""A parent job and its children: a tiled forest's tiles (:mod:`farm.tiles`) and a long
render's frame chunks (:mod:`farm.chunks`). The parent writes its child rows once, held, in
batches with a heartbeat between them; at each later delivery it lets the fair window send
what it may and looks at the children by counts: one failed (after its own retries) fails the
parent, naming it, and stops the others; one canceled cancels the parent."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from farm.dispatch import Dispatcher
from farm.fair import pump
from farm.settings import FarmSettings
from farm.store import Claim, JobStore
from schemas.jobs import JobState

BATCH = 2000  # child rows per insert, and per heartbeat of the parent while it writes them

Summary = dict[str, tuple[int, float]]


def with_request(store: JobStore, claim: Claim) -> Claim | None:
    """A child's claim with its parent's request under its own params (a tile row holds only
    its forest job and cell, a chunk its render job, frames and pool); None if the parent is
    gone."""
    parent = store.get(str(claim.params.get("parent", "")))
    if parent is None:
        return None
    return dataclasses.replace(claim, params={**dict(parent.params or {}), **claim.params})


def write_children(
    store: JobStore,
    claim: Claim,
    kind: str,
    rows: list[tuple[str, dict[str, Any]]],
    made: int,
    lease_s: float,
    noun: str,
) -> str | None:
    """Write the child rows from ``made`` on (``rows``: id and params each); None when done,
    else what happened (canceled while writing: the rows written so far go with it; lost)."""
    job_id = claim.job_id
    store.set_tiles(job_id, len(rows))  # the fair window looks for jobs with children
    for start in range(made, len(rows), BATCH):
        batch = rows[start : start + BATCH]
        store.add_children(claim, kind, batch)
        stage = f"writing {noun} {start + len(batch)}/{len(rows)}"
        beat = store.heartbeat(claim, lease_s, 0.0, stage)
        if beat is None:
            return "lost"
        if beat:
            store.cancel_family(job_id, children_only=True)
            store.finish(claim, JobState.CANCELED, error="canceled on request")
            return JobState.CANCELED
    return None


def look(
    store: JobStore,
    dispatcher: Dispatcher,
    settings: FarmSettings,
    claim: Claim,
    name: Callable[[dict[str, Any]], str],
) -> tuple[str | None, Summary]:
    """Pump, then the children's counts by state: the parent failed (the first failed child
    named by ``name`` of its params) or canceled, or None while it goes on."""
    job_id = claim.job_id
    pump(store, dispatcher, settings)
    summary = store.child_summary(job_id)
    failed = store.failed_child(job_id) if JobState.FAILED in summary else None
    if failed is not None:
        store.cancel_family(job_id, children_only=True)  # the others stop
        store.finish(claim, JobState.FAILED, error=f"{name(failed[0])}: {failed[1]}")
        return JobState.FAILED, summary
    if JobState.CANCELED in summary:
        store.finish(claim, JobState.CANCELED, error="canceled on request")
        return JobState.CANCELED, summary
    return None, summary
