"""Write the JSON Schema of every wire model to ``schemas/json/``: ``python -m schemas.export``.

The files are committed; ``tests/test_schemas.py`` fails when a model changes without them.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from pydantic import BaseModel

from schemas.grammar import Grammar
from schemas.jobs import (
    ForestRequest,
    Job,
    JobLog,
    JobPage,
    PresetList,
    RenderRequest,
    TreeRequest,
    WorkerList,
)
from schemas.metrics import RenderMetrics
from schemas.recipe import Recipe, RecipeList
from schemas.tileset import TileSetManifest

MODELS: dict[str, type[BaseModel]] = {
    "grammar": Grammar,
    "metrics": RenderMetrics,
    "tileset": TileSetManifest,
    "tree-request": TreeRequest,
    "forest-request": ForestRequest,
    "render-request": RenderRequest,
    "job": Job,
    "job-page": JobPage,
    "job-log": JobLog,
    "workers": WorkerList,
    "presets": PresetList,
    "recipe": Recipe,
    "recipes": RecipeList,
}
FOLDER = Path(__file__).parent / "json"


def schema_text(model: type[BaseModel]) -> str:
    return json.dumps(model.model_json_schema(), indent=2, sort_keys=True) + "\n"


def main() -> int:
    FOLDER.mkdir(exist_ok=True)
    for name, model in MODELS.items():
        path = FOLDER / f"{name}.schema.json"
        path.write_text(schema_text(model), encoding="utf-8")
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
