"""``POST /v1/trees``: one tree, answered synchronously as a USD or glTF (.glb) file."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any, get_args
from urllib.parse import quote

from fastapi import APIRouter
from fastapi.responses import Response

from farm.requests import options_from_request
from forest.errors import ForestError
from forest.export import single_file, write_forest
from forest.growth.generate import generate_forest
from schemas.jobs import SceneFormat, TreeRequest
from service.deps import ServicesDep
from service.errors import forest_error
from service.inputs import check_cost, library_settings, resolve_grammar
from service.routes.jobs import ARTIFACT_TYPES
from service.security import Tenant

router = APIRouter(prefix="/v1/trees", tags=["trees"])

MEDIA_TYPES = {fmt: ARTIFACT_TYPES[f".{fmt}"] for fmt in get_args(SceneFormat)}
_BINARY = {"schema": {"type": "string", "format": "binary"}}
RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "The tree as USD or glTF binary (the `format` asked for)",
        "content": {mt: _BINARY for mt in MEDIA_TYPES.values()},
    },
    400: {"description": "Body that is not JSON (bytes that do not decode)"},
    413: {"description": "Request body too large"},
}


@router.post("", response_class=Response, responses=RESPONSES)
def create_tree(req: TreeRequest, services: ServicesDep, tenant: Tenant) -> Response:
    s = services.settings
    grammar, cg = resolve_grammar(req, s, 1, s.max_tree_pieces)
    check_cost(req, s, cg.expected_pieces, 1)  # generated in this process
    options = options_from_request(req)
    name = f"{req.preset or grammar.name}-{req.seed}.{req.format}"
    with tempfile.TemporaryDirectory(prefix="forest-tree-") as tmp:
        try:
            forest = generate_forest(
                grammar,
                req.seed,
                options,
                settings=library_settings(s, s.max_tree_pieces),
                compiled=cg,
            )
            out = Path(tmp) / f"tree.{req.format}"
            # one file answers: pictures only where the file carries them (.usdz, .glb); a
            # .usda/.usdc keeps flat colours rather than name a folder the client never gets
            textures = single_file(out)
            path = write_forest(forest, out, skinned=req.skinned, textures=textures)
        except ForestError as exc:
            raise forest_error(exc) from None
        data = path.read_bytes()
    return Response(
        data,
        media_type=MEDIA_TYPES[req.format],
        headers={"Content-Disposition": attachment(name)},
    )


def attachment(name: str) -> str:
    """``Content-Disposition`` of a download named ``name`` (any Unicode, from a grammar's
    name): an ASCII ``filename``, and where that is not ``name`` the RFC 6266 ``filename*``
    (RFC 5987: UTF-8, percent-encoded). A header is Latin-1: ``a名`` there was a 500."""
    fallback = "".join(c if c.isascii() and (c.isalnum() or c in "-_.") else "_" for c in name)
    header = f'attachment; filename="{fallback}"'
    return header if fallback == name else f"{header}; filename*=UTF-8''{quote(name, safe='')}"
