"""``POST /v1/forests``: a forest job (202); the scene arrives as the job's artifact."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from schemas.jobs import ForestRequest, Job
from service.deps import IdempotencyKey, ServicesDep
from service.errors import field_error
from service.inputs import resolve_grammar
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
    if req.trees > s.max_forest_trees:
        raise field_error(["trees"], f"at most {s.max_forest_trees} trees", "limit_error")
    resolve_grammar(req, s, req.trees, s.max_forest_pieces)
    return submit(services, "forest", req.model_dump(mode="json"), idempotency_key, tenant)
