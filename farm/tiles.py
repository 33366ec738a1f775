"""Tiled forest jobs (``tile_size``): the forest job fans out into one ``forest_tile`` job per
tile of its grid and, once every tile completed, writes the root layer that holds the tiles'
files as payloads.

The tile jobs' ids derive from the forest job's id and the tile, so a second delivery of the
forest job finds the tiles it made and makes none twice. The forest job does not wait in a
worker: each delivery looks at its tiles and, unless they are all done, goes back to the
queue to look again in :data:`TILE_POLL_S` (as Celery's chord_unlock polls a group). What a
tile job runs (generate its trees, write its file) is the worker's; where the tiles lie is
the library's plan (:mod:`forest.growth.tiling`, :mod:`forest.usd.tiled`).
"""

from __future__ import annotations

import hashlib
import math
import shutil
from typing import Any

from farm.artifacts import ArtifactStore
from farm.db import JobRow
from farm.dispatch import Dispatcher
from farm.store import Claim, JobStore
from schemas.jobs import ForestRequest, JobState
from schemas.tiles import tile_grid

TILE_KIND = "forest_tile"
TILE_POLL_S = 0.5  # how often a tiled forest job looks at its tiles


def tile_job_id(parent: str, i: int, j: int) -> str:
    """The job id of tile ``(i, j)`` of a tiled forest job."""
    return hashlib.md5(f"{parent}:tile:{i}_{j}".encode(), usedforsecurity=False).hexdigest()


def tile_job_ids(parent: str, params: dict[str, Any]) -> list[tuple[int, int, str]]:
    """``(i, j, job id)`` of every tile of a forest job's ``params`` (none if not tiled)."""
    size = params.get("tile_size")
    if not size:
        return []
    nx, nz = tile_grid(tuple(params["area"]), float(size))
    return [(i, j, tile_job_id(parent, i, j)) for j in range(nz) for i in range(nx)]


def tile_count(req: ForestRequest) -> int:
    """How many tile jobs a forest request makes (1: it is not tiled, the job is its own)."""
    return math.prod(tile_grid(req.area, req.tile_size)) if req.tile_size else 1


def is_tiled(kind: str, params: dict[str, Any]) -> bool:
    """A forest job that joins tiles rather than generating a scene itself."""
    return kind == "forest" and bool(params.get("tile_size"))


def tile_artifact(i: int, j: int) -> str:
    """A tile's file in its forest job's artifacts (beside the root layer ``scene.*``)."""
    return f"scene_tile_{i}_{j}.usdc"


def artifact_owner(claim: Claim) -> str:
    """The job whose artifacts a job's files join: a tile's go beside its forest's root
    layer."""
    if claim.kind == TILE_KIND:
        return str(claim.params.get("parent", claim.job_id))
    return claim.job_id


def cancel(store: JobStore, job_id: str, tenant: str | None = None) -> JobRow | None:
    """Cancel a job, and a tiled forest's tiles with it (:meth:`JobStore.cancel_jobs`); the
    job after, or None if there is no such job (of ``tenant``)."""
    row = store.get(job_id, tenant)
    if row is None:
        return None
    tiles = [t for _, _, t in tile_job_ids(job_id, dict(row.params or {}))]
    store.cancel_jobs([job_id, *tiles])
    return store.get(job_id)


def join(store: JobStore, dispatcher: Dispatcher, artifacts: ArtifactStore, claim: Claim) -> str:
    """One delivery of a tiled forest job: create its tile jobs and send them as one Celery
    group (the first delivery), then look at them: all completed, write the root layer and
    complete; a tile failed (after its own retries) or canceled, end so; else record their
    mean progress and come back in :data:`TILE_POLL_S`. Answers what happened; a store or
    broker error is raised (the caller retries the delivery)."""
    from forest.usd.tiled import TileEntry, write_root

    job_id, params = claim.job_id, claim.params
    tiles = tile_job_ids(job_id, params)
    specs = [(t, {**params, "parent": job_id, "tile": [i, j]}) for i, j, t in tiles]  # TileJob
    new = store.create_children(claim, TILE_KIND, specs)
    if new:
        dispatcher.send_group(new, TILE_KIND)
    states = store.child_states([t for _, _, t in tiles])
    failed = [(k, st) for k, st in enumerate(states) if st.state == JobState.FAILED]
    if failed:
        k, st = failed[0]
        cancel(store, job_id)  # the other tiles stop
        i, j, _ = tiles[k]
        store.finish(claim, JobState.FAILED, error=f"tile {i}_{j}: {st.error}")
        return JobState.FAILED
    if any(st.state == JobState.CANCELED for st in states):
        store.finish(claim, JobState.CANCELED, error="canceled on request")
        return JobState.CANCELED
    done = sum(st.state == JobState.COMPLETED for st in states)
    if done < len(states):
        progress = sum(1.0 if st.state == JobState.COMPLETED else st.progress for st in states)
        store.park(claim, 0.95 * progress / len(states), f"tiles {done}/{len(states)}")
        dispatcher.send(job_id, claim.kind, countdown=TILE_POLL_S)
        return "waiting"
    req = ForestRequest.model_validate(params)
    entries = [TileEntry.from_json((st.result or {})["tile"]) for st in states]
    name = f"scene.{req.format}"
    scratch = artifacts.scratch(job_id)
    try:
        root = write_root(
            scratch / name, entries, frames=req.frames, fps=req.fps,
            meta={"trees": req.trees, "area": list(req.area), "tile_size": req.tile_size,
                  "seed": req.seed, "tiles": len(entries)},
        )  # fmt: skip
        artifacts.publish(job_id, root, name)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    result = {
        "trees": req.trees,
        "pieces": sum(int((st.result or {}).get("pieces", 0)) for st in states),
        "frames": req.frames,
        "scene": name,
        "tiles": len(states),
    }
    names = sorted([name] + [tile_artifact(i, j) for i, j, _ in tiles])
    ok = store.finish(claim, JobState.COMPLETED, artifacts=names, result=result)
    return JobState.COMPLETED if ok else "lost"
