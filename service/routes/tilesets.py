"""``POST /v1/tilesets``: a bark tile set quilted from the caller's photographs (a job, 202);
trees, forests and renders name it by its job id in ``tiles``."""

from __future__ import annotations

import hashlib
import tempfile
from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, File, Form, UploadFile
from fastapi.responses import JSONResponse

from forest.bark.images import check_example_header
from forest.errors import ForestError
from forest.sniff import HEAD_BYTES, describe, sniff_bytes
from schemas.jobs import TILESET_EXAMPLES, Job, JobCost, Seed, TileSetJob
from service.deps import IdempotencyKey, ServicesDep
from service.errors import field_error
from service.security import Tenant
from service.views import UPLOAD_ERRORS, submit

router = APIRouter(prefix="/v1/tilesets", tags=["tilesets"])

SUFFIX = {"png": ".png", "jpeg": ".jpg"}
# an uploaded photograph's caps (the CLI reads larger examples: MAX_EXAMPLE_PIXELS)
MAX_UPLOAD_BYTES = 16 << 20
MAX_UPLOAD_PIXELS = 4096 * 4096


def checked_example(data: bytes, k: int, size: int) -> str:
    """The file suffix of upload ``k`` once its bytes and header pass; 422 naming
    ``examples[k]`` otherwise. Only the header is decoded here (the job reads the pixels)."""
    where: list[str | int] = ["examples", k]
    if len(data) > MAX_UPLOAD_BYTES:
        raise field_error(where, f"{len(data):,} bytes: at most {MAX_UPLOAD_BYTES:,} a photograph")
    kind = sniff_bytes(data[:HEAD_BYTES])
    if kind not in SUFFIX:
        raise field_error(where, f"{describe(kind)}, not a PNG or JPEG photograph")
    with tempfile.TemporaryDirectory(prefix="forest-tileset-") as tmp:
        path = Path(tmp) / f"example{SUFFIX[kind]}"
        path.write_bytes(data)
        try:
            check_example_header(path, f"examples.{k}", size, MAX_UPLOAD_PIXELS)
        except ForestError as exc:
            raise field_error(where, exc.message) from None
    return SUFFIX[kind]


@router.post("", status_code=202, response_model=Job, responses=UPLOAD_ERRORS)
def create_tileset(
    services: ServicesDep,
    tenant: Tenant,
    examples: Annotated[
        list[UploadFile],
        File(description=f"1-{TILESET_EXAMPLES} bark photographs: PNG or JPEG, grey or RGB"),
    ],
    per_class: Annotated[int, Form(ge=1, le=16)] = 8,
    size: Annotated[int, Form(ge=64, le=512)] = 256,
    seed: Annotated[Seed, Form()] = 0,
    priority: Annotated[int, Form(ge=0, le=9)] = 5,
    idempotency_key: IdempotencyKey = None,
) -> JSONResponse:
    """A tile-set job (multipart form): its photographs (``examples``, each at least ``size``
    pixels wide and high, at most 4096 x 4096 and 16 MiB, no alpha) quilted into
    ``per_class`` bark tiles and as many fork tiles of ``size`` pixels (the CLI's ``forest
    tiles``). Its artifacts are the tile set (``manifest.json``, ``bark.<UDIM>.png``, ...;
    the manifest names each photograph by its SHA-256); give its id as ``tiles`` to a tree,
    forest or render."""
    if not 1 <= len(examples) <= TILESET_EXAMPLES:
        raise field_error(["examples"], f"give 1-{TILESET_EXAMPLES} photographs")
    inputs: dict[str, bytes] = {}
    digests = []
    for k, upload in enumerate(examples):
        data = upload.file.read()
        name = f"example_{k}{checked_example(data, k, size)}"
        inputs[name] = data
        digests.append(hashlib.sha256(data).hexdigest())
    params = TileSetJob(
        examples=list(inputs),
        sha256=digests,
        per_class=per_class,
        size=size,
        seed=seed,
        priority=priority,
    ).model_dump(mode="json")
    # its files count against the tenant's quota of queued bytes: the tiles it writes
    tile_bytes = 2 * per_class * size * size * 3 * 2  # a PNG and an array slice each
    cost = JobCost(pieces=0, frames=0, tiles=0, scene_bytes=tile_bytes, units=0)
    return submit(services, "tileset", params, idempotency_key, tenant, inputs, cost=cost)
