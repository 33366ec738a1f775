"""The job graph: a job may wait for others (its ``after``), as a render waits for the forest
it draws. It is written held and ``blocked``; each pump (:func:`farm.fair.pump`, which runs
whenever a job ends, at each reaper round and on each submission) first settles the blocked
jobs: one whose jobs have all completed is unblocked (the window then sends it in its turn),
one whose job failed fails, and one whose job was canceled is canceled, each saying which
job and why, which in turn settles what waits for it. A render that waits for a forest learns
the forest's scene here, once the forest has written it."""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from farm.db import JobRow, utcnow
from farm.store import HELD, IN_BATCH
from schemas.jobs import JobState

MAX_ROUNDS = 8
"""Settling rounds per pump: a chain settles one link a round (a canceled forest cancels its
render, which cancels what waits for the render...); a longer chain goes on at the next pump."""


def settle(s: Session) -> int:
    """Unblock, fail or cancel the blocked jobs whose jobs have ended; how many changed.
    Runs inside the window's exclusive transaction. Every blocked job is looked at, a page of
    :data:`IN_BATCH` at a time in id order (jobs waiting on one long job must not hide those
    behind them)."""
    changed = 0
    for _ in range(MAX_ROUNDS):
        n, last = 0, ""
        while True:
            blocked = s.scalars(
                select(JobRow)
                .where(JobRow.blocked.is_(True), JobRow.state == JobState.QUEUED, JobRow.id > last)
                .order_by(JobRow.id)
                .limit(IN_BATCH)
            ).all()
            if not blocked:
                break
            last = blocked[-1].id
            ids = sorted({p for row in blocked for p in row.after or []})
            parents = {
                r.id: r
                for k in range(0, len(ids), IN_BATCH)
                for r in s.scalars(select(JobRow).where(JobRow.id.in_(ids[k : k + IN_BATCH])))
            }
            n += sum(_settle_one(row, parents) for row in blocked)
        changed += n
        if n == 0:
            break
    return changed


def _settle_one(row: JobRow, parents: dict[str, JobRow]) -> bool:
    after = row.after or []
    for pid in after:
        parent = parents.get(pid)
        if parent is None:
            return _end(row, JobState.FAILED, f"job {pid} it waited for is gone")
        if parent.state == JobState.FAILED:
            return _end(row, JobState.FAILED, f"job {pid} it waited for failed: {parent.error}")
        if parent.state == JobState.CANCELED:
            return _end(row, JobState.CANCELED, f"job {pid} it waited for was canceled")
    if not all(parents[pid].state == JobState.COMPLETED for pid in after):
        return False
    if row.kind == "render" and not (row.params or {}).get("scene"):
        forest = parents[(row.params or {}).get("forest_job") or after[0]]
        scene = (forest.result or {}).get("scene")
        if not scene or not forest.artifacts or scene not in forest.artifacts:
            return _end(row, JobState.FAILED, f"the forest job {forest.id} has no scene artifact")
        if str(scene).endswith(".glb"):
            return _end(
                row,
                JobState.FAILED,
                f"the forest job {forest.id} wrote glTF (.glb); the renderer reads USD formats",
            )
        row.params = _with(row.params, scene=scene)
    row.blocked = False
    row.stage = HELD
    return True


def _end(row: JobRow, state: JobState, error: str) -> bool:
    row.state, row.stage, row.error = state, state, error
    row.blocked = False
    row.finished_at = utcnow()
    return True


def _with(params: dict[str, Any] | None, **values: Any) -> dict[str, Any]:
    """A new dict (a JSON column sees an assignment, not an in-place change)."""
    return {**(params or {}), **values}
