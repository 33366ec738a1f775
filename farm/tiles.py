"""Tiled forest jobs (``tile_size``): the forest job fans out into one ``forest_tile`` job per
tile of its grid and, once every tile completed, writes the root layer that holds the tiles'
files as payloads.

The tile jobs' ids derive from the forest job's id and the tile, and their rows are written in
order, in batches (:mod:`farm.family`: within every database's parameter limit; the forest
job's lease is heartbeated between batches), so a second delivery of the forest job goes on
where the first stopped. A tile row holds only its forest job and cell (the worker reads the
request from the forest job) and is written held: the fair window (:mod:`farm.fair`) sends
tiles as workers free up. The forest job does not wait in a worker: each delivery looks at its
tiles (counts by state, one query) and, unless they are all done, goes back to the queue to
look again in :func:`poll_s` (as Celery's chord_unlock polls a group). What a tile job runs
(generate its trees, write its file) is the worker's; where the tiles lie is the library's plan
(:mod:`forest.growth.tiling`, :mod:`forest.usd.tiled`).
"""

from __future__ import annotations

import hashlib
import math
import shutil
from typing import Any

from farm.artifacts import ArtifactStore
from farm.db import JobRow
from farm.dispatch import Dispatcher
from farm.fair import CHUNK_KIND, TILE_KIND
from farm.family import look, write_children
from farm.settings import FarmSettings
from farm.store import Claim, JobStore
from schemas.jobs import ForestRequest, JobState
from schemas.tiles import tile_grid

TILE_POLL_S = 0.5  # how often a tiled forest job looks at its tiles (at least)
MAX_POLL_S = 10.0


def poll_s(tiles: int) -> float:
    """How long a tiled forest job waits between looks: longer for more tiles (a look counts
    them all; the window refills on each tile's end without it)."""
    return min(MAX_POLL_S, TILE_POLL_S * max(1.0, tiles / 2000))


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


def n_tiles(params: dict[str, Any]) -> int:
    """How many tiles a forest job's ``params`` make (0: not tiled)."""
    size = params.get("tile_size")
    return math.prod(tile_grid(tuple(params["area"]), float(size))) if size else 0


def tile_count(req: ForestRequest) -> int:
    """How many tile jobs a forest request makes (1: it is not tiled, the job is its own)."""
    return math.prod(tile_grid(req.area, req.tile_size)) if req.tile_size else 1


def is_tiled(kind: str, params: dict[str, Any]) -> bool:
    """A forest job that joins tiles rather than generating a scene itself."""
    return kind == "forest" and bool(params.get("tile_size"))


def tile_artifact(i: int, j: int) -> str:
    """A tile's file in its forest job's artifacts (beside the root layer ``scene.*``)."""
    return f"scene_tile_{i}_{j}.usdc"


def stand_tile_artifact(i: int, j: int, layer: str) -> str:
    """A recipe forest's layer tile in its forest job's artifacts."""
    return f"scene_tile_{i}_{j}_{layer}.usdc"


def artifact_owner(claim: Claim) -> str:
    """The job whose artifacts a job's files join: a tile's go beside its forest's root
    layer, a render chunk's frames into its render job's folder."""
    if claim.kind in (TILE_KIND, CHUNK_KIND):
        return str(claim.params.get("parent", claim.job_id))
    return claim.job_id


def cancel(store: JobStore, job_id: str, tenant: str | None = None) -> JobRow | None:
    """Cancel a job, and a tiled forest's tiles with it (:meth:`JobStore.cancel_family`: by
    ``parent``, a few statements whatever the tile count; no broker message is revoked, a
    canceled tile's message is skipped when it arrives); the job after, or None if there is
    no such job (of ``tenant``)."""
    row = store.get(job_id, tenant)
    if row is None:
        return None
    store.cancel_family(job_id)
    return store.get(job_id)


def _tile_name(params: dict[str, Any]) -> str:
    i, j = params.get("tile", ["?", "?"])
    return f"tile {i}_{j}"


def set_up(store: JobStore, claim: Claim, lease_s: float, made: int | None = None) -> str | None:
    """Write the tile rows not written yet (``made`` of them are: counted if not given; held,
    in batches, heartbeating the forest job's lease between them); None when done, else what
    happened (canceled, lost)."""
    job_id = claim.job_id
    made = store.count_children(job_id) if made is None else made
    if made >= n_tiles(claim.params):
        return None
    rows = [
        (t, {"parent": job_id, "tile": [i, j]}) for i, j, t in tile_job_ids(job_id, claim.params)
    ]
    return write_children(store, claim, TILE_KIND, rows, made, lease_s, "tiles")


def join(
    store: JobStore,
    dispatcher: Dispatcher,
    artifacts: ArtifactStore,
    claim: Claim,
    settings: FarmSettings,
) -> str:
    """One delivery of a tiled forest job: write its tile rows (the first delivery), let the
    fair window send what it may, then look at the tiles: all completed, write the root layer
    and complete; a tile failed (after its own retries) or canceled, end so; else record their
    mean progress and come back in :func:`poll_s`. Answers what happened; a store or
    broker error is raised (the caller retries the delivery)."""
    from forest.usd.tiled import TileEntry, write_root

    job_id, params = claim.job_id, claim.params
    n = n_tiles(params)
    summary = store.child_summary(job_id)
    made = sum(count for count, _ in summary.values())
    if made < n:
        ended = set_up(store, claim, settings.lease_s, made)
        if ended is not None:
            return ended
    ended, summary = look(store, dispatcher, settings, claim, _tile_name)
    if ended is not None:
        return ended
    done = summary.get(JobState.COMPLETED, (0, 0.0))[0]
    if done < n:
        progress = done + sum(p for st, (_, p) in summary.items() if st != JobState.COMPLETED)
        if store.park(claim, 0.95 * progress / n, f"tiles {done}/{n}"):
            dispatcher.send(job_id, claim.kind, countdown=poll_s(n))
            return "waiting"
        if store.heartbeat(claim, settings.lease_s) is None:
            return "lost"
        # canceled while it looked: end it here (a parked job asked to cancel is never claimed)
        store.cancel_family(job_id, children_only=True)
        store.finish(claim, JobState.CANCELED, error="canceled on request")
        return JobState.CANCELED
    # the root layer lists the tiles in grid order (rows of z, then x), whatever order ran
    states = sorted(store.child_results(job_id), key=lambda pr: tuple(pr[0]["tile"])[::-1])
    req = ForestRequest.model_validate(params)
    if req.recipe is not None:
        return _join_stand(store, artifacts, claim, req, states)
    entries = [TileEntry.from_json((r or {})["tile"]) for _, r in states]
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
        "pieces": sum(int((r or {}).get("pieces", 0)) for _, r in states),
        "frames": req.frames,
        "scene": name,
        "tiles": len(states),
    }
    names = sorted([name] + [tile_artifact(*p["tile"]) for p, _ in states])
    ok = store.finish(claim, JobState.COMPLETED, artifacts=names, result=result)
    return JobState.COMPLETED if ok else "lost"


def _join_stand(
    store: JobStore,
    artifacts: ArtifactStore,
    claim: Claim,
    req: ForestRequest,
    states: list[tuple[dict[str, Any], dict[str, Any] | None]],
) -> str:
    """A recipe's tiled forest, every tile done: the root layer over the terrain referencing
    each layer's tiles (the stand placed again: the root names its layers and carries the
    ground)."""
    from farm.requests import loaded_recipe, stand_size
    from forest.stand.generate import plan_stand
    from forest.usd.stand import LayerFile, write_stand_root

    job_id = claim.job_id
    loaded = loaded_recipe(req)
    trees, area = stand_size(req, loaded.recipe)
    stand = plan_stand(loaded, trees, area, req.seed)
    files = [LayerFile.from_json(e) for _, r in states for e in (r or {}).get("stand_tile", [])]
    name = f"scene.{req.format}"
    scratch = artifacts.scratch(job_id)
    try:
        root = write_stand_root(scratch / name, stand, files, frames=req.frames, fps=req.fps)
        artifacts.publish(job_id, root, name)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    layers = {
        layer.name: len(t)
        for layer, t in zip(stand.recipe.layers, stand.placement.layers, strict=True)
    }
    result = {
        "trees": stand.trees,
        "layers": layers,
        "pieces": sum(int((r or {}).get("pieces", 0)) for _, r in states),
        "frames": req.frames,
        "scene": name,
        "tiles": len(states),
        "recipe": stand.recipe.name,
    }
    names = sorted([name] + [f.asset.removeprefix("./") for f in files])
    ok = store.finish(claim, JobState.COMPLETED, artifacts=names, result=result)
    return JobState.COMPLETED if ok else "lost"
