"""Per-tenant quotas on cost, checked before a job is queued: each job carries an estimate
(:class:`schemas.jobs.JobCost`: pieces x frames, tiles, bytes, from the same figures as the
per-request caps, :mod:`forest.cost`); a tenant's queued and running jobs may sum to at most
``tenant_max_cost`` piece-frames and ``tenant_max_tiles`` tiles. Over a quota: 429 with
Retry-After (it fits once some of the tenant's work ends), or 422 when the job alone is over it
(it never will). Either names the quota."""

from __future__ import annotations

import math

from fastapi import HTTPException
from fastapi.exceptions import RequestValidationError

from forest.cost import forest_cost
from schemas.jobs import ForestRequest, JobCost
from service.errors import RETRY_AFTER_S, field_error
from service.settings import ServiceSettings

QUOTAS = (("tenant_max_cost", "units", "piece-frames"), ("tenant_max_tiles", "tiles", "tiles"))


def job_cost(pieces: float, frames: int, tiles: int = 0, scene_bytes: int = 0) -> JobCost:
    whole = math.ceil(pieces)
    return JobCost(
        pieces=whole,
        frames=frames,
        tiles=tiles,
        scene_bytes=scene_bytes,
        units=whole * max(frames, 1),
    )


def forest_job_cost(req: ForestRequest, pieces_per_tree: float, tiles: int) -> JobCost:
    """A forest job's estimate: every tree's expected pieces; its files' bytes are a tile's
    scene (:func:`forest.cost.forest_cost`) times the tiles (or the one scene)."""
    per_tile_trees = math.ceil(req.trees / max(tiles, 1))
    scene = forest_cost(
        pieces_per_tree * per_tile_trees,
        per_tile_trees,
        req.frames,
        req.segments,
        req.format,
        req.skinned,
    ).scene_bytes
    return job_cost(pieces_per_tree * req.trees, req.frames, tiles, scene * max(tiles, 1))


def over_quota(
    settings: ServiceSettings, cost: JobCost, load: tuple[int, int], field: list[str | int]
) -> HTTPException | RequestValidationError | None:
    """The answer when ``cost`` on top of the tenant's ``load`` (cost, tiles of its queued
    and running jobs) is over a quota; None when it fits."""
    for (quota, attr, unit), used in zip(QUOTAS, load, strict=True):
        cap: int = getattr(settings, quota)
        wants: int = getattr(cost, attr)
        if wants > cap:
            loc: list[str | int] = ["tile_size"] if attr == "tiles" else field
            return field_error(
                loc,
                f"about {wants} {unit}; the tenant quota {quota} is {cap}: this job can never "
                "fit (fewer trees, frames or tiles)",
                "limit_error",
            )
        if used + wants > cap:
            return HTTPException(
                429,
                f"tenant quota {quota} exceeded: {used} {unit} queued or running + {wants} of "
                f"this job > {cap}; retry when some of your jobs have finished",
                headers={"Retry-After": str(RETRY_AFTER_S)},
            )
    return None
