"""``POST /v1/renders``: a render job (202) of a finished forest job's scene, or of an uploaded
USD file (``POST /v1/renders/upload``); artifacts ``preview.png`` and ``metrics.json``."""

from __future__ import annotations

import hashlib
from typing import Annotated

from fastapi import APIRouter, File, Form, UploadFile
from fastapi.responses import JSONResponse

from schemas.jobs import Job, JobState, RenderRequest
from service.deps import IdempotencyKey, ServicesDep
from service.errors import field_error
from service.quotas import job_cost
from service.security import CallerDep, Tenant
from service.settings import ServiceSettings
from service.views import ERRORS, UPLOAD_ERRORS, check_after, submit

router = APIRouter(prefix="/v1/renders", tags=["renders"])


def check_caps(
    s: ServiceSettings, width: int, height: int, frames: int, at: list[str | int] | None = None
) -> None:
    """The service's caps on image size and frame count (beyond the request schema's);
    ``at``: where the settings sit in the request (a forest request's ``render``)."""
    for name, value in (("width", width), ("height", height)):
        if value > s.max_image_size:
            raise field_error(
                [*(at or []), name], f"at most {s.max_image_size} pixels", "limit_error"
            )
    if frames > s.max_render_frames:
        raise field_error(
            [*(at or []), "frames"], f"at most {s.max_render_frames} frames", "limit_error"
        )


@router.post("", status_code=202, response_model=Job, responses=ERRORS)
def create_render(
    req: RenderRequest,
    services: ServicesDep,
    tenant: Tenant,
    who: CallerDep,
    idempotency_key: IdempotencyKey = None,
) -> JSONResponse:
    check_caps(services.settings, req.width, req.height, req.frames)
    # another tenant's forest is no such job, except to an admin (the render is the admin's)
    row = services.store.get(req.forest_job, who.scope)
    if row is None or row.kind != "forest":
        raise field_error(["forest_job"], "no such forest job")
    after = check_after(services, req.after, who.scope)
    if row.state in (JobState.QUEUED, JobState.ACTIVE) and not row.cancel_requested:
        # not drawn yet: the render waits for it and learns its scene then (farm.graph)
        check_renderable(row.params)
        scene, pieces = None, (row.estimate or {}).get("pieces", 0)
        after = [row.id, *(a for a in after if a != row.id)]
    else:
        if row.state != JobState.COMPLETED:
            state = JobState.CANCELED if row.cancel_requested else row.state
            raise field_error(["forest_job"], f"the forest job is {state}, not completed")
        scene = (row.result or {}).get("scene")
        if not scene or services.artifacts.path(row.id, scene) is None:
            raise field_error(["forest_job"], "the forest job has no scene artifact")
        if scene.endswith(".glb"):
            raise field_error(["forest_job"], GLB)
        pieces = (row.result or {}).get("pieces", 0)
    # it draws the bark of the forest's own tile set (its indices follow that set)
    tiles = (row.params or {}).get("tiles")
    params = req.model_dump(mode="json") | {"scene": scene, "tiles": tiles}  # RenderJob
    # the estimate: the forest's pieces drawn once per frame
    cost = job_cost(int(pieces), req.frames)
    return submit(
        services,
        "render",
        params,
        idempotency_key,
        tenant,
        cost=cost,
        field=["frames"],
        after=after or None,
    )


GLB = "the forest job wrote glTF (.glb); the renderer reads USD formats"


def check_renderable(forest_params: dict[str, object], field: str = "forest_job") -> None:
    """422 unless the forest a render waits for will write a scene the renderer reads."""
    if forest_params.get("format") == "glb":
        raise field_error([field], GLB.replace("wrote", "writes"))


USD_MAGIC = {b"#usda": ".usda", b"PXR-USDC": ".usdc", b"PK\x03\x04": ".usdz"}


@router.post("/upload", status_code=202, response_model=Job, responses=UPLOAD_ERRORS)
def upload_render(
    services: ServicesDep,
    tenant: Tenant,
    scene: Annotated[UploadFile, File(description="A USD scene: .usda, .usdc or .usdz")],
    width: Annotated[int, Form(ge=1, le=8192)] = 640,
    height: Annotated[int, Form(ge=1, le=8192)] = 480,
    tess_max: Annotated[float, Form(ge=1, le=64, allow_inf_nan=False)] = 8.0,
    frame: Annotated[int, Form(ge=0, le=10_000)] = 0,
    frames: Annotated[int, Form(ge=1, le=10_000)] = 1,
    staged: Annotated[bool, Form()] = True,
    idempotency_key: IdempotencyKey = None,
) -> JSONResponse:
    """A render job of an uploaded USD scene (multipart form: ``scene`` file + the same
    settings as ``POST /v1/renders``); the scene must follow the forest scene contract."""
    check_caps(services.settings, width, height, frames)
    data = scene.file.read()
    suffix = next((sfx for magic, sfx in USD_MAGIC.items() if data.startswith(magic)), None)
    if suffix is None:
        raise field_error(["scene"], "not a USD file (.usda, .usdc or .usdz)")
    name = f"upload{suffix}"
    params = {  # schemas.jobs.RenderJob
        "forest_job": None,
        "scene": name,
        "scene_sha256": hashlib.sha256(data).hexdigest(),
        "width": width,
        "height": height,
        "tess_max": tess_max,
        "frame": frame,
        "frames": frames,
        "staged": staged,
    }
    # the scene is in place before the job is sent, so no worker can see the job without it
    return submit(services, "render", params, idempotency_key, tenant, inputs={name: data})
