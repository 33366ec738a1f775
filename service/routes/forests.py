"""``POST /v1/forests``: a forest job (202); the scene arrives as the job's artifact."""

from __future__ import annotations

import math

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from farm.tiles import tile_count
from schemas.jobs import ForestRequest, Job
from service.deps import IdempotencyKey, ServicesDep
from service.errors import field_error
from service.inputs import check_cost, resolve_grammar, resolve_recipe
from service.quotas import forest_job_cost, job_cost
from service.security import Tenant
from service.views import ERRORS, submit

router = APIRouter(prefix="/v1/forests", tags=["forests"])


@router.post("", status_code=202, response_model=Job, responses=ERRORS)
def create_forest(
    req: ForestRequest,
    services: ServicesDep,
    tenant: Tenant,
    idempotency_key: IdempotencyKey = None,
) -> JSONResponse:
    s = services.settings
    # a tiled forest: the caps hold per tile (each tile is a job of its own), on average
    per_tile = math.ceil(req.trees / tile_count(req))
    if per_tile > s.max_forest_trees:
        where = " per tile" if req.tile_size else ""
        raise field_error(["trees"], f"at most {s.max_forest_trees} trees{where}", "limit_error")
    if req.recipe is not None:  # a mixed forest: a root layer and one file per layer
        plan = resolve_recipe(req, s, s.max_forest_trees, s.max_forest_pieces)
        cost = job_cost(plan.pieces, req.frames, 0, plan.scene_bytes)
        params = req.model_dump(mode="json")
        return submit(
            services, "forest", params, idempotency_key, tenant, cost=cost, field=["trees"]
        )
    _, cg = resolve_grammar(req, s, per_tile, s.max_forest_pieces)
    check_cost(req, s, cg, per_tile, " per tile" if req.tile_size else "")
    cost = forest_job_cost(req, cg.expected_pieces, tile_count(req) if req.tile_size else 0)
    params = req.model_dump(mode="json")
    return submit(services, "forest", params, idempotency_key, tenant, cost=cost, field=["trees"])
