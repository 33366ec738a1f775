"""``POST /v1/forests``: a forest job (202); the scene arrives as the job's artifact."""

from __future__ import annotations

import math

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from farm.tiles import tile_count
from farm.webhooks import refusal
from schemas.jobs import ForestRequest, Job
from service.deps import IdempotencyKey, ServicesDep
from service.errors import field_error
from service.inputs import check_cost, resolve_grammar, resolve_recipe
from service.quotas import forest_job_cost, job_cost
from service.routes.renders import check_caps, check_renderable
from service.security import CallerDep, Tenant
from service.views import ERRORS, accepted, check_after, check_tiles, enqueue

router = APIRouter(prefix="/v1/forests", tags=["forests"])


@router.post("", status_code=202, response_model=Job, responses=ERRORS)
def create_forest(
    req: ForestRequest,
    services: ServicesDep,
    tenant: Tenant,
    who: CallerDep,
    idempotency_key: IdempotencyKey = None,
) -> JSONResponse:
    """A forest job; with ``render``, also its render job, which waits for it."""
    s = services.settings
    after = check_after(services, req.after, who.scope)
    after = list(dict.fromkeys(after + check_tiles(services, req.tiles, who.scope, True)))
    if req.render is not None:
        check_renderable(req.model_dump(mode="json"), "render")
        check_caps(s, req.render.width, req.render.height, req.render.frames, ["render"])
        # the render's webhook host too: no forest job is made for a render that cannot be
        refused = refusal(req.render.webhook, s) if req.render.webhook else None
        if refused is not None:
            raise field_error(["render", "webhook"], refused)
    # a tiled forest: the caps hold per tile (each tile is a job of its own), on average
    per_tile = math.ceil(req.trees / tile_count(req))
    if per_tile > s.max_forest_trees:
        where = " per tile" if req.tile_size else ""
        raise field_error(["trees"], f"at most {s.max_forest_trees} trees{where}", "limit_error")
    if req.recipe is not None:  # a mixed forest: a root layer and one file per layer
        plan = resolve_recipe(req, s, s.max_forest_trees, s.max_forest_pieces)
        cost = job_cost(plan.pieces, req.frames, 0, plan.scene_bytes)
    else:
        _, cg = resolve_grammar(req, s, per_tile, s.max_forest_pieces)
        check_cost(req, s, cg, per_tile, " per tile" if req.tile_size else "")
        cost = forest_job_cost(req, cg.expected_pieces, tile_count(req) if req.tile_size else 0)
    params = req.model_dump(mode="json")
    row = enqueue(
        services, "forest", params, idempotency_key, tenant, cost=cost, field=["trees"],
        after=after or None,
    )  # fmt: skip
    if req.render is not None and not row.then:  # (a repeated request has its render)
        render = req.render.model_dump(mode="json")
        # schemas.jobs.RenderJob; it draws the forest's own tile set
        render |= {"forest_job": row.id, "after": [], "scene": None, "tiles": req.tiles}
        enqueue(
            services,
            "render",
            render,
            None,
            tenant,
            cost=job_cost(cost.pieces, req.render.frames),
            field=["render", "frames"],
            after=[row.id],
        )
        row = services.store.get(row.id) or row
    return accepted(row, services)
