"""Shared fixtures: small seeded forests, written once per session."""

from __future__ import annotations

from pathlib import Path

import pytest

from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.scene import write_scene


@pytest.fixture(scope="session")
def windy_forest() -> Forest:
    return generate_forest(load_preset("almond"), 11, ForestOptions(trees=3, frames=4, fps=6))


@pytest.fixture(scope="session")
def skinned_scene(windy_forest: Forest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("scene") / "forest.usda"
    return write_scene(windy_forest, path, skinned=True)
