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


@pytest.mark.parametrize("bad", [-0.5, 65.0, float("nan")])
def test_render_request_refuses_a_bad_lod_pixels(bad: float) -> None:
    from pydantic import ValidationError

    from schemas.jobs import RenderRequest

    with pytest.raises(ValidationError) as err:
        RenderRequest(forest_job="f1", lod_pixels=bad)
    # the name is the field's, or leads the message of the whole-request finiteness check
    e = err.value.errors()[0]
    assert e["loc"] == ("lod_pixels",) or e["msg"].startswith("Value error, lod_pixels:")
    assert RenderRequest(forest_job="f1").lod_pixels == 0.5
    assert RenderRequest(forest_job="f1", lod_pixels=None).lod_pixels is None
