"""What a job's request means to the library: the generation options of a tree or forest
request. The service (synchronous trees, cost checks) and the worker (forest and tile jobs)
read requests through here, so both generate the same forest from the same request."""

from __future__ import annotations

from dataclasses import replace

from forest.growth.generate import ForestOptions
from forest.growth.wind import Wind
from schemas.jobs import ForestRequest, TreeRequest


def options_from_request(req: TreeRequest) -> ForestOptions:
    """The generation options of an API request (a ForestRequest adds trees, area, placement)."""
    options = ForestOptions(
        frames=req.frames, fps=req.fps, segments=req.segments, wind=Wind(strength_deg=req.wind_deg)
    )
    if isinstance(req, ForestRequest):
        options = replace(options, trees=req.trees, area=req.area, placement=req.placement)
    return options
