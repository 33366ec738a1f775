"""Procedural bark photographs-to-be: texture examples for the default tile set, made here so
the package ships no image whose origin or licence is in doubt.

Furrowed bark is a height field: plates separated by a network of long, wavy vertical furrows
(ridged value noise stretched along the trunk, its x domain-warped), broken by a few short
horizontal cracks, with fine grain on top; colour runs from dark furrows to grey-brown plates,
with a faint lichen tint in patches. Only additions, products, ``abs`` and cubic-spline
interpolation are used, so the same seed gives the same bytes on every machine.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

F64 = NDArray[np.float64]

FURROW = np.array([38.0, 27.0, 20.0])
PLATE = np.array([146.0, 128.0, 108.0])
LICHEN = np.array([118.0, 132.0, 96.0])


def value_noise(
    rng: np.random.Generator,
    height: int,
    width: int,
    cell_y: float,
    cell_x: float,
    shift_x: F64 | None = None,
) -> F64:
    """``(height, width)`` float64 in about [0, 1]: uniform random values on a lattice of
    ``cell_y x cell_x`` pixel cells, interpolated with cubic splines; ``shift_x`` (same shape,
    pixels) moves each sample across, for domain warping."""
    pad = 4 + (int(np.ceil(np.abs(shift_x).max() / cell_x)) if shift_x is not None else 0)
    ny, nx = int(np.ceil(height / cell_y)) + 4, int(np.ceil(width / cell_x)) + 2 * pad
    lattice = rng.random((ny, nx))
    yy, xx = np.meshgrid(
        np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij"
    )
    if shift_x is not None:
        xx = xx + shift_x
    return ndimage.map_coordinates(
        lattice, [yy / cell_y + 1.5, xx / cell_x + pad], order=3, mode="nearest"
    )


def _ridged(n: F64) -> F64:
    """1 on the noise's mid level, falling to 0 at its extremes: thin lines along contours."""
    return np.clip(1.0 - 2.0 * np.abs(n - 0.5), 0.0, 1.0)


def bark_example(height: int, width: int, seed: int, furrow_px: float = 20.0) -> NDArray[np.uint8]:
    """An RGB bark texture, ``(height, width, 3)`` uint8; ``furrow_px`` is the typical spacing
    of furrows across the trunk."""
    rng = np.random.default_rng(seed)
    f = furrow_px
    hw = (height, width)
    # furrows: ridged noise, long along y, domain-warped across x so they wander and merge
    warp = 1.5 * f * (value_noise(rng, *hw, 5 * f, 4 * f) - 0.5)
    warp += 0.25 * f * (value_noise(rng, *hw, 0.8 * f, 2 * f) - 0.5)
    furrows = _ridged(value_noise(rng, *hw, 5 * f, f, shift_x=warp)) ** 5
    furrows += 0.35 * _ridged(value_noise(rng, *hw, 3 * f, 0.6 * f, shift_x=warp)) ** 3
    # plates bulge between furrows, rough at several scales; short cross cracks break them
    plate = np.zeros(hw)
    for k, amp in enumerate((0.5, 0.25, 0.15, 0.1)):
        s = 2.0**-k
        plate = plate + amp * value_noise(rng, *hw, 2 * f * s, 1.2 * f * s)
    cracks = np.clip(3.0 * (value_noise(rng, *hw, 0.4 * f, 1.5 * f) - 0.75), 0.0, 1.0)
    grain = value_noise(rng, *hw, 3.0, 1.0)
    h = 0.3 + 0.6 * plate - 0.8 * np.minimum(furrows, 1.0) - 0.3 * cracks + 0.15 * (grain - 0.5)
    h = np.clip(h, 0.0, 1.0)[..., None]
    lichen = np.clip(2.5 * (value_noise(rng, *hw, 8 * f, 8 * f) - 0.55), 0.0, 0.6)
    lit = PLATE + lichen[..., None] * (LICHEN - PLATE)
    rgb = FURROW + h * (lit - FURROW)
    return np.clip(rgb + 0.5, 0, 255).astype(np.uint8)
