"""Procedural species bark (forest.bark.barkgen): deterministic, the right shape and dtype,
and each species in its colour family (what a photo of that bark would average to)."""

from __future__ import annotations

import numpy as np
import pytest

from forest.bark.barkgen import SPECIES, species_example


@pytest.mark.parametrize("name", list(SPECIES))
def test_species_example_is_deterministic_rgb(name: str) -> None:
    a = species_example(name, 96, 80, 3)
    assert a.shape == (96, 80, 3) and a.dtype == np.uint8
    assert np.array_equal(a, species_example(name, 96, 80, 3))
    assert not np.array_equal(a, species_example(name, 96, 80, 4))
    assert a.std() > 5  # textured, not flat


def _mean(name: str) -> np.ndarray:
    return species_example(name, 192, 192, 1).reshape(-1, 3).mean(axis=0)


def test_species_colour_families() -> None:
    r, g, b = _mean("birch")
    assert min(r, g, b) > 170  # white
    r, g, b = _mean("pine")
    assert r > g + 40 and g > b  # orange-red
    r, g, b = _mean("spruce")
    assert r > g + 20 and r < 160  # red-brown, darker than pine
    assert _mean("almond").max() < 80  # dark grey
    for name in ("oak", "willow", "poplar", "hazel", "almond"):
        r, g, b = _mean(name)
        assert r >= g >= b and r - b < 40, name  # grey to grey-brown


def test_unknown_species_names_the_known_ones() -> None:
    with pytest.raises(ValueError, match="oak"):
        species_example("baobab", 8, 8, 0)
