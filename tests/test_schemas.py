"""Committed JSON Schema exports match the models (regenerate: python -m schemas.export)."""

import json

import pytest

from forest.growth.presets import load_preset, preset_names
from schemas.export import FOLDER, MODELS, schema_text


@pytest.mark.parametrize("name", sorted(MODELS))
def test_exported_schema_has_not_drifted(name: str) -> None:
    committed = (FOLDER / f"{name}.schema.json").read_text(encoding="utf-8")
    assert committed == schema_text(MODELS[name]), (
        f"schemas/json/{name}.schema.json is stale: run `python -m schemas.export`"
    )


@pytest.mark.parametrize("name", preset_names())
def test_presets_round_trip_through_the_schema(name: str) -> None:
    grammar = load_preset(name)
    again = type(grammar).model_validate(json.loads(grammar.model_dump_json()))
    assert again == grammar
