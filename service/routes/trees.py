"""``POST /v1/trees``: one tree as a USD or glTF (.glb) file.

The tree is made by a ``tree`` job on the workers (their queue, their memory and CPU limits),
never in the API process, whose memory stays flat however big or many the trees are. The route
waits for the job up to ``tree_wait_s`` and answers its file (200), or else the job (202, as
the forest and render routes do) for the client to follow."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import Annotated, Any, get_args
from urllib.parse import quote

from fastapi import APIRouter, Header, HTTPException, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, Response
from starlette.background import BackgroundTask

from farm.db import JobRow
from farm.reaper import delete_artifacts
from farm.store import FINISHED
from schemas.jobs import Job, JobState, SceneFormat, TreeRequest
from service.deps import Services, ServicesDep
from service.inputs import check_cost, resolve_grammar, resolve_recipe
from service.quotas import job_cost
from service.routes.jobs import ARTIFACT_TYPES
from service.security import CallerDep, Tenant
from service.views import accepted, check_tiles, enqueue

log = logging.getLogger(__name__)
router = APIRouter(prefix="/v1/trees", tags=["trees"])

MEDIA_TYPES = {fmt: ARTIFACT_TYPES[f".{fmt}"] for fmt in get_args(SceneFormat)}
_BINARY = {"schema": {"type": "string", "format": "binary"}}
RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "The tree as USD or glTF binary (the `format` asked for)",
        "content": {mt: _BINARY for mt in MEDIA_TYPES.values()},
    },
    202: {
        "description": "The tree's job, not done within `FOREST_TREE_WAIT_S` (or at once with "
        "`Prefer: respond-async`): follow `Location`; its artifact is the file",
        "model": Job,
    },
    400: {"description": "Body that is not JSON (bytes that do not decode)"},
    409: {"description": "The tree's job was canceled before it was done"},
    413: {"description": "Request body too large"},
}
# the first polls come quickly (a small tree takes a fraction of a second), later ones less often
_FIRST_POLL_S, _MAX_POLL_S = 0.05, 0.5

PreferHeader = Annotated[
    str | None,
    Header(
        alias="Prefer",
        max_length=256,
        description="RFC 7240: `respond-async` answers 202 with the job at once; `wait=<s>` "
        "waits at most that long (never longer than the server's FOREST_TREE_WAIT_S).",
    ),
]


def wait_preference(prefer: str | None, server_wait_s: float) -> float:
    """How long to wait for the job: the server's limit, shortened by ``Prefer``."""
    wait_s = server_wait_s
    for pref in (prefer or "").split(","):
        name, _, value = pref.split(";")[0].partition("=")
        name = name.strip().lower()
        if name == "respond-async":
            return 0.0
        if name == "wait":
            # an unreadable preference is ignored (RFC 7240 section 2)
            with contextlib.suppress(ValueError):
                wait_s = min(wait_s, max(0.0, float(value.strip().strip('"'))))
    return wait_s


def _submit(
    req: TreeRequest, services: Services, tenant: str, scope: str | None
) -> tuple[JobRow, str]:
    """Check the request (422 before any work) and queue its job; the job and the file name."""
    s = services.settings
    check_tiles(services, req.tiles, scope, False)
    if req.recipe is not None:  # a small mixed stand, answered as one file
        plan = resolve_recipe(req, s, s.max_forest_trees, s.max_tree_pieces, flat=True)
        cost = job_cost(plan.pieces, req.frames, 0, plan.scene_bytes)
        params = req.model_dump(mode="json")
        row = enqueue(services, "tree", params, None, tenant, cost=cost, field=["trees"])
        return row, f"{plan.loaded.recipe.name}-{req.seed}.{req.format}"
    grammar, cg = resolve_grammar(req, s, 1, s.max_tree_pieces)
    check_cost(req, s, cg, 1)
    cost = job_cost(cg.expected_pieces, req.frames)
    # no idempotency key: a 200 deletes the job's file once sent, so a replay would find none
    params = req.model_dump(mode="json")
    row = enqueue(services, "tree", params, None, tenant, cost=cost, field=["frames"])
    return row, f"{req.preset or grammar.name}-{req.seed}.{req.format}"


async def _wait(services: Services, row: JobRow, wait_s: float, request: Request) -> JobRow | None:
    """The job once finished or after ``wait_s``; None if the client went away meanwhile (the
    job is canceled then: nobody else knows its id)."""
    deadline = time.monotonic() + wait_s
    pause = _FIRST_POLL_S
    while row.state not in FINISHED and (left := deadline - time.monotonic()) > 0:
        if await request.is_disconnected():
            log.info("tree job %s: the client went away; canceled", row.id)
            await run_in_threadpool(services.store.cancel_family, row.id)
            return None
        await asyncio.sleep(min(pause, left))
        pause = min(pause * 1.5, _MAX_POLL_S)
        now = await run_in_threadpool(services.store.get, row.id)
        row = now if now is not None else row
    return row


@router.post("", response_class=Response, responses=RESPONSES)
async def create_tree(
    req: TreeRequest,
    request: Request,
    services: ServicesDep,
    tenant: Tenant,
    who: CallerDep,
    prefer: PreferHeader = None,
) -> Response:
    row, name = await run_in_threadpool(_submit, req, services, tenant, who.scope)
    wait_s = wait_preference(prefer, services.settings.tree_wait_s)
    done = await _wait(services, row, wait_s, request)
    if done is None:
        return Response(status_code=204)  # the client is gone: what it is sent does not matter
    row = done
    if row.state == JobState.FAILED:
        raise HTTPException(422, f"the tree could not be made (job {row.id}): {row.error}")
    if row.state == JobState.CANCELED:
        raise HTTPException(409, f"the tree's job {row.id} was canceled")
    artifact = f"tree.{req.format}"
    path = services.artifacts.path(row.id, artifact) if row.state == JobState.COMPLETED else None
    if path is None:  # not done in time: the job, to follow
        return accepted(row, services)
    # streamed from the artifact store (never read into the API's memory), then deleted: the
    # file was the answer; the job stays, listing it deleted (artifacts_deleted_at)
    return FileResponse(
        path,
        media_type=MEDIA_TYPES[req.format],
        headers={"Content-Disposition": attachment(name)},
        background=BackgroundTask(delete_artifacts, services.store, services.artifacts, row.id),
    )


def attachment(name: str) -> str:
    """``Content-Disposition`` of a download named ``name`` (any Unicode, from a grammar's
    name): an ASCII ``filename``, and where that is not ``name`` the RFC 6266 ``filename*``
    (RFC 5987: UTF-8, percent-encoded). A header is Latin-1: ``a名`` there was a 500."""
    fallback = "".join(c if c.isascii() and (c.isalnum() or c in "-_.") else "_" for c in name)
    header = f'attachment; filename="{fallback}"'
    return header if fallback == name else f"{header}; filename*=UTF-8''{quote(name, safe='')}"
