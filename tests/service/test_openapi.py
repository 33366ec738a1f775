"""schemathesis over the published OpenAPI: no 5xx, responses match their schemas, content
types and status codes are documented (a bounded number of examples, fixed seed)."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from service_harness import Server

SMALL_CAPS = {  # generated requests stay cheap: the point is the contract, not the work
    "FOREST_MAX_FOREST_TREES": "4",
    "FOREST_MAX_FOREST_PIECES": "3000",
    "FOREST_MAX_TREE_PIECES": "3000",
    "FOREST_MAX_FRAMES": "4",
    "FOREST_MAX_IMAGE_SIZE": "256",
    "FOREST_MAX_RENDER_FRAMES": "4",
}


def test_openapi_contract(make_server: Callable[..., Server], tmp_path: Path) -> None:
    server = make_server(SMALL_CAPS, workers=0)
    st = Path(sys.executable).with_name("schemathesis")
    proc = subprocess.run(
        [
            str(st), "run", f"{server.url}/openapi.json",
            "--max-examples", "25",
            "--seed", "7",
            "--checks",
            "not_a_server_error,response_schema_conformance,content_type_conformance,"
            "status_code_conformance",
            "--request-timeout", "30",
        ],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stdout[-6000:] + proc.stderr[-2000:]
    assert server.get("/healthz").status_code == 200
