"""mkdocs hook: the HTTP API page's OpenAPI reference, made from the app at build time.

``service.app:create_app`` builds the same document that ``forest serve`` answers at
``/openapi.json``; it is added to the site as ``openapi.json`` (never committed, so it cannot
go stale), where the page's Swagger UI reads it. Building the app opens nothing: the job store
and the broker are only connected to when the app starts serving.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

OPENAPI_URI = "openapi.json"


def openapi_text() -> str:
    from service.app import create_app
    from service.settings import ServiceSettings

    with tempfile.TemporaryDirectory() as data:
        app = create_app(ServiceSettings(data_dir=Path(data)), reaper=False)
        return json.dumps(app.openapi(), indent=2, sort_keys=True) + "\n"


def on_files(files: Files, config: Any) -> Files:
    files.append(File.generated(config, OPENAPI_URI, content=openapi_text()))
    return files
