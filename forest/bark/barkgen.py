"""Procedural bark photographs-to-be: texture examples for the default tile set, made here so
the package ships no image whose origin or licence is in doubt.

Furrowed bark is a height field: plates separated by a network of long, wavy vertical furrows
(ridged value noise stretched along the trunk, its x domain-warped), broken by a few short
horizontal cracks, with fine grain on top; colour runs from dark furrows to grey-brown plates,
with a faint lichen tint in patches. Only additions, products, ``abs`` and cubic-spline
interpolation are used, so the same seed gives the same bytes on every machine.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from types import ModuleType

import numpy as np
from numpy.typing import NDArray

from forest.extras import require

F64 = NDArray[np.float64]

FURROW = np.array([38.0, 27.0, 20.0])
PLATE = np.array([146.0, 128.0, 108.0])
LICHEN = np.array([118.0, 132.0, 96.0])


def _ndimage() -> ModuleType:
    """scipy.ndimage on first use: a third of a second to import, and only making bark
    needs it (the grammar checks import this module for its species names). Making bark is
    a developer's task (rebuilding the shipped tile sets, ``forest bench tiles``), so scipy
    comes with the dev extra, not with the core install."""
    require("dev", "scipy", path="bark")
    from scipy import ndimage

    return ndimage


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
    return _ndimage().map_coordinates(
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


# ---------------------------------------------------------------- species bark
#
# Each species' example is a height field ``h`` (0 deep in a furrow or crack, 1 on the outer
# bark) and an albedo, lit by a soft light from the upper left (a photo's baked lighting),
# with cavities darkened. The scale is ~1 m across a 384 px example (~2.6 mm per pixel).
# Only +, *, /, sqrt, abs, min/max and cubic splines are used (all correctly rounded or
# exact), so a seed gives the same bytes everywhere.

LIGHT = np.array([-0.45, 0.55, 0.70])  # x right, y up the image, z out of the bark
LIGHT = LIGHT / np.sqrt((LIGHT * LIGHT).sum())


def noise(
    rng: np.random.Generator,
    hw: tuple[int, int],
    cell_y: float,
    cell_x: float,
    shift_x: F64 | None = None,
    shift_y: F64 | None = None,
) -> F64:
    """:func:`value_noise` with an optional shift along y too; ``(h, w)`` float64 in ~[0, 1]."""
    if shift_y is None:
        return value_noise(rng, *hw, cell_y, cell_x, shift_x)
    height, width = hw
    pad_y = 4 + int(np.ceil(np.abs(shift_y).max() / cell_y))
    pad_x = 4 + (int(np.ceil(np.abs(shift_x).max() / cell_x)) if shift_x is not None else 0)
    ny = int(np.ceil(height / cell_y)) + 2 * pad_y
    nx = int(np.ceil(width / cell_x)) + 2 * pad_x
    lattice = rng.random((ny, nx))
    yy, xx = np.meshgrid(
        np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij"
    )
    yy = yy + shift_y
    if shift_x is not None:
        xx = xx + shift_x
    return _ndimage().map_coordinates(
        lattice, [yy / cell_y + pad_y, xx / cell_x + pad_x], order=3, mode="nearest"
    )


def fbm(
    rng: np.random.Generator,
    hw: tuple[int, int],
    cell_y: float,
    cell_x: float,
    octaves: int = 4,
    gain: float = 0.5,
) -> F64:
    """Sum of ``octaves`` value noises, each half the cell of the last; ``(h, w)`` in ~[0, 1]."""
    out = np.zeros(hw)
    amp, total = 1.0, 0.0
    for k in range(octaves):
        s = 2.0**-k
        out += amp * noise(rng, hw, max(cell_y * s, 1.0), max(cell_x * s, 1.0))
        total += amp
        amp *= gain
    return out / total


def cells(
    rng: np.random.Generator,
    hw: tuple[int, int],
    cell_y: float,
    cell_x: float,
    jitter: float = 0.8,
    stagger: bool = False,
    warp_x: F64 | None = None,
    warp_y: F64 | None = None,
) -> tuple[F64, F64, NDArray[np.int64]]:
    """Worley cells: one jittered point per ``cell_y x cell_x`` lattice cell (every other row
    shifted half a cell with ``stagger``, which makes diamonds). Returns, per pixel, the
    distances (in cell units, anisotropic) to the nearest and second-nearest points
    ``f1, f2`` ``(h, w)`` float64 and the nearest point's id ``(h, w)`` int64."""
    height, width = hw
    yy, xx = np.meshgrid(
        np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij"
    )
    if warp_x is not None:
        xx = xx + warp_x
    if warp_y is not None:
        yy = yy + warp_y
    gy, gx = yy / cell_y, xx / cell_x
    ny = int(np.ceil(height / cell_y)) + 8
    nx = int(np.ceil(width / cell_x)) + 9
    pts = 0.5 + jitter * (rng.random((ny, nx, 2)) - 0.5)
    if stagger:
        pts[1::2, :, 1] += 0.5
    iy = np.floor(gy).astype(np.int64)
    ix = np.floor(gx).astype(np.int64)
    best = np.full((2, *hw), np.inf)
    ids = np.zeros(hw, np.int64)
    for dy in (-1, 0, 1):
        for dx in (-2, -1, 0, 1, 2) if stagger else (-1, 0, 1):
            cy = np.clip(iy + dy + 4, 0, ny - 1)
            cx = np.clip(ix + dx + 4, 0, nx - 1)
            p = pts[cy, cx]
            d = np.sqrt((gy - (cy - 4 + p[..., 0])) ** 2 + (gx - (cx - 4 + p[..., 1])) ** 2)
            closer = d < best[0]
            best[1] = np.where(closer, best[0], np.minimum(best[1], d))
            best[0] = np.where(closer, d, best[0])
            ids = np.where(closer, cy * nx + cx, ids)
    return best[0], best[1], ids


def _cell_values(rng: np.random.Generator, ids: NDArray[np.int64]) -> F64:
    """A uniform random value per cell id, ``ids``' shape."""
    return rng.random(int(ids.max()) + 1)[ids]


def _smooth(x: F64) -> F64:
    """Smoothstep of ``x`` clipped to [0, 1]."""
    t = np.clip(x, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _palette(t: F64, stops: Sequence[tuple[float, tuple[float, float, float]]]) -> F64:
    """``(h, w, 3)`` colours interpolated piecewise-linearly at ``t`` between ``stops``
    (position, sRGB 0-255)."""
    xs = [s for s, _ in stops]
    return np.stack([np.interp(t, xs, [c[i] for _, c in stops]) for i in range(3)], axis=-1)


def shade(h: F64, relief: float, ambient: float = 0.45, cavity: float = 0.5) -> F64:
    """``(h, w)`` light factor of height field ``h`` (0 to 1) standing ``relief`` pixels
    proud: Lambert under :data:`LIGHT`, plus ambient light that deep places see less of."""
    gy, gx = np.gradient(h * relief)
    # image rows run down, the light's y up: a slope rising upwards faces the light
    nx, ny, nz = -gx, gy, np.ones_like(h)
    norm = np.sqrt(nx * nx + ny * ny + 1.0)
    lambert = np.clip((nx * LIGHT[0] + ny * LIGHT[1] + nz * LIGHT[2]) / norm, 0.0, 1.0)
    occl = 1.0 - cavity * (1.0 - np.clip(h, 0.0, 1.0))
    return (ambient + (1.0 - ambient) * lambert / LIGHT[2]) * occl


def _finish(albedo: F64, light: F64) -> NDArray[np.uint8]:
    return np.clip(albedo * light[..., None] + 0.5, 0, 255).astype(np.uint8)


def contour_distance(n: F64, level: float = 0.5) -> F64:
    """``(h, w)`` approximate distance in pixels from each pixel to the ``level`` contour of
    ``n`` (first-order: the value gap over the gradient's length), so lines drawn along a
    contour keep their width where the noise is flat."""
    gy, gx = np.gradient(n)
    return np.abs(n - level) / (np.sqrt(gx * gx + gy * gy) + 1e-4)


def _furrows(
    rng: np.random.Generator, hw: tuple[int, int], f: float, width: float, sets: int = 2
) -> F64:
    """``(h, w)``: 0 in a furrow, rising to 1 on a ridge. ``sets`` sets of long, wavy
    vertical contour lines of domain-warped value noise, ~``f`` px apart and ~``width`` px
    wide (varying), so they wander, merge and split as oak or poplar furrows do."""
    warp = 1.4 * f * (noise(rng, hw, 6 * f, 4 * f) - 0.5)
    warp += 0.3 * f * (noise(rng, hw, 0.9 * f, 2 * f) - 0.5)
    wide = width * (0.4 + 1.2 * noise(rng, hw, 3 * f, 2 * f))
    ridge = np.ones(hw)
    for k in range(sets):
        n = noise(rng, hw, (5 - k) * f, (1.1 - 0.2 * k) * f, shift_x=warp)
        ridge = np.minimum(ridge, _smooth(contour_distance(n) / wide))
    return ridge


def _valleys(
    rng: np.random.Generator,
    hw: tuple[int, int],
    f: float,
    level: float,
    soft: float = 0.1,
    length: float = 14.0,
) -> F64:
    """``(h, w)``: 0 down in a furrow, rising to 1 on a ridge. Furrows are where vertically
    stretched, domain-warped noise (~``f`` px across, ``length`` times that along) falls
    below ``level``: long, deep valleys that meet and part, not lines drawn on a surface;
    ``soft`` is how gently the walls rise."""
    warp = 1.0 * f * (noise(rng, hw, 0.7 * length * f, 4 * f) - 0.5)
    n = 0.7 * noise(rng, hw, length * f, f, shift_x=warp)
    n += 0.3 * noise(rng, hw, 0.35 * length * f, 0.5 * f, shift_x=warp)
    return _smooth((n - level) / soft)


def _cross_cracks(
    rng: np.random.Generator, hw: tuple[int, int], length: float, spacing: float, share: float
) -> F64:
    """``(h, w)`` 1 on short horizontal cracks (~``length`` px long, rows ~``spacing`` px
    apart, a ``share`` of them present), 0 elsewhere."""
    n = noise(rng, hw, spacing, 3 * length)
    line = _smooth(1.0 - contour_distance(n) / 1.5)
    keep = _smooth((noise(rng, hw, 0.6 * spacing, length) - (1.0 - share)) / 0.08)
    return line * keep


def _ribs(rng: np.random.Generator, hw: tuple[int, int], period: float, width: float) -> F64:
    """``(h, w)``: 0 down in a furrow, 1 on a ridge. Furrows run the height of the image
    about ``period`` px apart, wavering slowly, ~``width`` px wide (varying), here and there
    bridged by a ridge that crosses them. A bark tile's top and bottom share one edge
    pattern, so a furrow crossing them must sit at the same place across every tile: furrows
    this evenly spaced let each tile's interior be slid to meet them (the tile set's slide)
    and run on from tile to tile."""
    height, width_px = hw
    xx = np.arange(width_px, dtype=np.float64)[None, :].repeat(height, 0)
    waver = 0.35 * period * (noise(rng, hw, 6 * period, 3 * period) - 0.5) * 2
    waver += 0.12 * period * (noise(rng, hw, 1.5 * period, period) - 0.5) * 2
    phase = (xx + waver) / period
    dist = np.abs(phase - np.floor(phase) - 0.5) * period  # px from the furrow's centre line
    wide = width * (0.6 + 0.8 * noise(rng, hw, 4 * period, 0.5 * period))
    furrow = _smooth(1.0 - dist / wide)
    bridge = _smooth((noise(rng, hw, 0.8 * period, 0.7 * period) - 0.78) / 0.08)
    return 1.0 - furrow * (1.0 - 0.8 * bridge)


def _oak(rng: np.random.Generator, hw: tuple[int, int]) -> NDArray[np.uint8]:
    """Deep vertical furrows, evenly spaced, between long, thick grey-brown ridges, the
    ridges broken into blocks by a few cross cracks and furrowed by fibres."""
    f = 20.0
    # five furrows across a 128 px tile (see _ribs)
    ridge = _ribs(rng, hw, 128.0 / 5.0, 9.0)
    cracks = _cross_cracks(rng, hw, 0.7 * f, 2.2 * f, 0.4)
    fibres = noise(rng, hw, 14.0, 2.0)
    rough = fbm(rng, hw, 0.8 * f, 0.4 * f, 4)
    # a ridge's top is flat and rough, its walls steep: sqrt sharpens the profile
    h = np.sqrt(ridge) * (0.7 + 0.3 * rough - 0.12 * _smooth(1.0 - contour_distance(fibres)))
    h = h * (1.0 - 0.8 * cracks * ridge)
    grain = noise(rng, hw, 5.0, 1.2)
    h = np.clip(h + 0.05 * (grain - 0.5), 0.0, 1.0)
    tint = fbm(rng, hw, 3 * f, 3 * f, 3)
    albedo = _palette(
        h,
        [(0.0, (52, 41, 33)), (0.3, (72, 60, 49)), (0.7, (104, 92, 78)), (1.0, (132, 120, 104))],
    )
    albedo *= (0.88 + 0.24 * tint)[..., None]
    moss = _smooth((fbm(rng, hw, 4 * f, 4 * f, 3) - 0.62) / 0.15) * 0.25 * h
    albedo += moss[..., None] * (np.array([104.0, 112.0, 84.0]) - albedo)
    return _finish(albedo, shade(h, 14.0, ambient=0.5, cavity=0.4))


def _scales(
    rng: np.random.Generator,
    hw: tuple[int, int],
    cell_y: float,
    cell_x: float,
    crack: float,
    warp: float = 0.3,
) -> tuple[F64, F64, F64]:
    """Plates split by cracks: Worley cells of ``cell_y x cell_x`` px, wobbly edges. Returns
    ``(h, w)`` float64 ``edge`` (0 in a crack ``crack`` cell units wide, 1 inside a plate),
    ``lift`` (0 at a plate's top, 1 at its bottom edge: plates overlap downwards like
    shingles) and ``tone`` (a random value per plate)."""
    wx = warp * cell_x * (fbm(rng, hw, 0.5 * cell_y, 0.5 * cell_x, 3) - 0.5) * 2
    wy = warp * cell_y * (fbm(rng, hw, 0.5 * cell_y, 0.5 * cell_x, 3) - 0.5) * 2
    f1, f2, ids = cells(rng, hw, cell_y, cell_x, warp_x=wx, warp_y=wy)
    edge = _smooth((f2 - f1) / crack)
    # how far down its plate a pixel is: the plate's centre is where f1 is least
    cy = _ndimage().mean(
        np.arange(hw[0], dtype=np.float64)[:, None].repeat(hw[1], 1), ids, index=np.unique(ids)
    )
    centre = np.zeros(int(ids.max()) + 1)
    centre[np.unique(ids)] = cy
    lift = np.clip(0.5 + (np.arange(hw[0])[:, None] - centre[ids]) / cell_y, 0.0, 1.0)
    return edge, lift, _cell_values(rng, ids)


def _almond(rng: np.random.Generator, hw: tuple[int, int]) -> NDArray[np.uint8]:
    """Dark grey, fissured into small, thick, roughly square scales."""
    edge, lift, tone = _scales(rng, hw, 26.0, 20.0, 0.22, warp=0.35)
    fiss = _furrows(rng, hw, 30.0, 3.0, sets=1)
    rough = fbm(rng, hw, 8.0, 8.0, 3)
    h = edge * (0.55 + 0.25 * rough + 0.2 * lift) * (0.3 + 0.7 * fiss)
    h = np.clip(h + 0.06 * (noise(rng, hw, 2.0, 2.0) - 0.5), 0.0, 1.0)
    albedo = _palette(h, [(0.0, (22, 20, 19)), (0.5, (58, 54, 52)), (1.0, (104, 99, 95))])
    albedo *= (0.8 + 0.4 * tone)[..., None]
    return _finish(albedo, shade(h, 10.0, cavity=0.4))


def _birch(rng: np.random.Generator, hw: tuple[int, int]) -> NDArray[np.uint8]:
    """Chalk-white with dark horizontal lenticel dashes, a few peeling curls and one or two
    black diamond scars where branches were."""
    height, width = hw
    yy, xx = np.meshgrid(
        np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij"
    )
    white = _palette(
        fbm(rng, hw, 60.0, 90.0, 4),
        [(0.0, (196, 190, 178)), (0.5, (228, 225, 216)), (1.0, (240, 238, 232))],
    )
    # lenticels: thin horizontal dashes, 4 to 40 px long, 1 to 3 px tall
    n = noise(rng, hw, 9.0, 90.0)
    dash = _smooth(1.0 - contour_distance(n) / (0.8 + 1.2 * noise(rng, hw, 10.0, 20.0)))
    dash *= _smooth((noise(rng, hw, 5.0, 24.0) - 0.6) / 0.06)
    # diamonds: |dx| / a + |dy| / b < 1 around a few centres, with ragged edges
    k = max(1, round(height * width / 384.0**2 * 2))
    cy, cx = rng.random(k) * height, rng.random(k) * width
    a, b = 18 + 22 * rng.random(k), 28 + 30 * rng.random(k)
    rag = 0.25 * (fbm(rng, hw, 6.0, 6.0, 3) - 0.5)
    diamond = np.zeros(hw)
    for i in range(k):
        d = np.abs(xx - cx[i]) / a[i] + np.abs(yy - cy[i]) / b[i]
        diamond = np.maximum(diamond, _smooth((1.0 - d + rag) / 0.15))
    # rough dark bands and peeling papery strips
    peel = _smooth((noise(rng, hw, 8.0, 60.0) - 0.8) / 0.05)
    grey = _smooth((fbm(rng, hw, 30.0, 60.0, 4) - 0.62) / 0.1)
    dark = np.clip(0.9 * dash + diamond + 0.35 * grey, 0.0, 1.0)
    black = _palette(fbm(rng, hw, 5.0, 5.0, 3), [(0.0, (18, 16, 15)), (1.0, (70, 62, 56))])
    albedo = white + dark[..., None] * (black - white)
    albedo += 0.35 * peel[..., None] * (np.array([214.0, 180.0, 150.0]) - albedo)
    h = 0.8 - 0.5 * dark + 0.2 * peel + 0.05 * noise(rng, hw, 2.0, 4.0)
    return _finish(albedo, shade(h, 4.0, ambient=0.6, cavity=0.2))


def _pine(rng: np.random.Generator, hw: tuple[int, int]) -> NDArray[np.uint8]:
    """Orange-red papery plates, flaking in layers, split by darker grey-brown cracks."""
    edge, lift, tone = _scales(rng, hw, 70.0, 34.0, 0.16, warp=0.4)
    layers = fbm(rng, hw, 18.0, 14.0, 3)
    flakes = np.floor(layers * 6.0) / 6.0  # papery terraces
    h = edge * (0.5 + 0.3 * flakes + 0.2 * lift)
    h = np.clip(h + 0.05 * (noise(rng, hw, 2.0, 3.0) - 0.5), 0.0, 1.0)
    plate = _palette(
        flakes + 0.25 * (tone - 0.5),
        [(0.0, (120, 64, 44)), (0.4, (170, 92, 58)), (0.8, (204, 126, 84)), (1.0, (214, 160, 120))],
    )
    crack = _palette(noise(rng, hw, 6.0, 6.0), [(0.0, (38, 30, 27)), (1.0, (84, 70, 62))])
    albedo = crack + _smooth(edge * 1.4)[..., None] * (plate - crack)
    return _finish(albedo, shade(h, 7.0, cavity=0.35))


def _spruce(rng: np.random.Generator, hw: tuple[int, int]) -> NDArray[np.uint8]:
    """Red-brown bark of thin, small, rounded scales overlapping downwards."""
    edge, lift, tone = _scales(rng, hw, 24.0, 22.0, 0.1, warp=0.3)
    h = edge * (0.35 + 0.65 * lift * lift)
    h = np.clip(h + 0.05 * (noise(rng, hw, 2.0, 2.0) - 0.5), 0.0, 1.0)
    patch = fbm(rng, hw, 40.0, 40.0, 3)
    albedo = _palette(
        0.6 * tone + 0.4 * patch,
        [(0.0, (78, 50, 40)), (0.5, (124, 80, 60)), (1.0, (150, 110, 88))],
    )
    albedo *= (0.7 + 0.3 * edge)[..., None]
    return _finish(albedo, shade(h, 7.0, cavity=0.35))


def _diamond_ridges(
    rng: np.random.Generator,
    hw: tuple[int, int],
    cell_y: float,
    cell_x: float,
    ridge: float,
) -> F64:
    """``(h, w)`` height of a net of ridges (1) around diamond-shaped furrows (0): the
    borders of staggered, tall Worley cells, ``ridge`` cell units wide."""
    wx = 0.25 * cell_x * (fbm(rng, hw, cell_y, cell_x, 3) - 0.5) * 2
    f1, f2, _ = cells(rng, hw, cell_y, cell_x, jitter=0.5, stagger=True, warp_x=wx)
    return 1.0 - _smooth((f2 - f1) / ridge)


def _willow(rng: np.random.Generator, hw: tuple[int, int]) -> NDArray[np.uint8]:
    """Grey-brown, deep furrows leaning left and right that cross into a net of
    diamond-shaped ridges."""
    f = 18.0
    rows = np.arange(hw[0], dtype=np.float64)[:, None].repeat(hw[1], 1)
    wobble = 0.6 * f * (noise(rng, hw, 3 * f, 3 * f) - 0.5)
    ridge = np.ones(hw)
    for lean in (0.3, -0.3):  # two families of sheared vertical contours cross as diamonds
        n = noise(rng, hw, 6 * f, f, shift_x=lean * rows + wobble)
        ridge = np.minimum(ridge, _smooth(np.minimum(contour_distance(n), 12.0) / 8.0))
    rough = fbm(rng, hw, 12.0, 6.0, 3)
    h = ridge * (0.7 + 0.3 * rough) + 0.05 * (noise(rng, hw, 6.0, 1.5) - 0.5)
    h = np.clip(h, 0.0, 1.0)
    tint = fbm(rng, hw, 80.0, 80.0, 3)
    albedo = _palette(h, [(0.0, (40, 34, 29)), (0.5, (98, 88, 76)), (1.0, (148, 138, 124))])
    albedo *= (0.88 + 0.24 * tint)[..., None]
    return _finish(albedo, shade(h, 12.0, cavity=0.35))


def _poplar(rng: np.random.Generator, hw: tuple[int, int]) -> NDArray[np.uint8]:
    """Grey-brown, long parallel ridges between shallower, narrower furrows than oak's."""
    ridge = _furrows(rng, hw, 20.0, 6.0)
    net = _diamond_ridges(rng, hw, 120.0, 22.0, 0.35)
    rough = fbm(rng, hw, 20.0, 6.0, 4)
    h = np.sqrt(ridge) * (0.55 + 0.2 * rough + 0.25 * net)
    h = np.clip(h + 0.05 * (noise(rng, hw, 8.0, 1.5) - 0.5), 0.0, 1.0)
    tint = fbm(rng, hw, 60.0, 60.0, 3)
    albedo = _palette(h, [(0.0, (52, 46, 40)), (0.5, (112, 106, 96)), (1.0, (166, 160, 150))])
    albedo *= (0.9 + 0.2 * tint)[..., None]
    return _finish(albedo, shade(h, 9.0, cavity=0.4))


def _hazel(rng: np.random.Generator, hw: tuple[int, int]) -> NDArray[np.uint8]:
    """Smooth, shiny grey-brown with pale, horizontally stretched lenticels."""
    base = _palette(
        fbm(rng, hw, 40.0, 120.0, 4),
        [(0.0, (96, 80, 68)), (0.5, (124, 106, 92)), (1.0, (146, 130, 114))],
    )
    f1, _, ids = cells(rng, hw, 9.0, 24.0, jitter=0.9)
    size = 0.1 + 0.2 * _cell_values(rng, ids)
    present = _cell_values(rng, ids) < 0.35
    lent = present * _smooth((size - f1) / 0.1)
    pale = np.array([198.0, 184.0, 160.0])
    albedo = base + 0.8 * lent[..., None] * (pale - base)
    # a silvery skin over parts and a soft sheen: the bark is smooth
    skin = _smooth((fbm(rng, hw, 50.0, 30.0, 4) - 0.55) / 0.15)
    albedo += 0.3 * skin[..., None] * (np.array([160.0, 156.0, 150.0]) - albedo)
    sheen = fbm(rng, hw, 90.0, 24.0, 2)
    h = 0.7 + 0.15 * lent + 0.06 * noise(rng, hw, 20.0, 6.0)
    light = shade(h, 3.0, ambient=0.7, cavity=0.1) * (0.9 + 0.25 * sheen)
    return _finish(albedo, light)


def _pine_lower(rng: np.random.Generator, hw: tuple[int, int]) -> NDArray[np.uint8]:
    """The foot of an old pine: thick grey-brown plates split by deep, mostly vertical
    fissures, a rust-red glow of inner bark down in them."""
    f = 28.0
    ridge = _valleys(rng, hw, 0.55 * f, 0.36, 0.1)
    edge, lift, tone = _scales(rng, hw, 2.5 * f, 1.4 * f, 0.08, warp=0.35)
    rough = fbm(rng, hw, 10.0, 6.0, 4)
    h = np.sqrt(ridge) * (0.4 + 0.6 * edge) * (0.65 + 0.2 * rough + 0.15 * lift)
    h = np.clip(h + 0.05 * (noise(rng, hw, 6.0, 1.5) - 0.5), 0.0, 1.0)
    albedo = _palette(
        h + 0.15 * (tone - 0.5),
        [(0.0, (58, 34, 24)), (0.25, (100, 58, 38)), (0.5, (92, 80, 70)), (1.0, (128, 116, 102))],
    )
    albedo *= (0.9 + 0.2 * fbm(rng, hw, 60.0, 60.0, 3))[..., None]
    return _finish(albedo, shade(h, 14.0, cavity=0.5))


def _birch_lower(rng: np.random.Generator, hw: tuple[int, int]) -> NDArray[np.uint8]:
    """The foot of an old birch: black-grey corky bark in thick vertical ridges between deep
    fissures, a few strips of the white bark left between them."""
    f = 22.0
    ridge = _valleys(rng, hw, 0.6 * f, 0.37, 0.1)
    cracks = _cross_cracks(rng, hw, 0.8 * f, 2.0 * f, 0.5)
    rough = fbm(rng, hw, 8.0, 4.0, 4)
    h = np.sqrt(ridge) * (0.65 + 0.35 * rough) * (1.0 - 0.7 * cracks)
    h = np.clip(h + 0.05 * (noise(rng, hw, 4.0, 1.5) - 0.5), 0.0, 1.0)
    dark = _palette(h, [(0.0, (12, 11, 10)), (0.5, (40, 37, 34)), (1.0, (78, 74, 70))])
    # white bark survives in patches on the ridges, long and narrow
    white = _smooth((fbm(rng, hw, 50.0, 14.0, 3) - 0.6) / 0.06) * _smooth(h / 0.6)
    pale = np.array([214.0, 208.0, 198.0])
    albedo = dark + white[..., None] * (pale - dark)
    return _finish(albedo, shade(h, 12.0, cavity=0.45))


LOWER: dict[str, Callable[[np.random.Generator, tuple[int, int]], NDArray[np.uint8]]] = {
    "pine": _pine_lower,
    "birch": _birch_lower,
}
"""Bark of the lower trunk, for species whose foot looks other than the rest: like
:data:`SPECIES`."""


SPECIES: dict[str, Callable[[np.random.Generator, tuple[int, int]], NDArray[np.uint8]]] = {
    "oak": _oak,
    "almond": _almond,
    "birch": _birch,
    "pine": _pine,
    "spruce": _spruce,
    "willow": _willow,
    "poplar": _poplar,
    "hazel": _hazel,
}
"""Bark generators by species: ``(rng, (height, width))`` -> ``(height, width, 3)`` uint8."""


def species_example(species: str, height: int, width: int, seed: int) -> NDArray[np.uint8]:
    """A ``(height, width, 3)`` uint8 example of ``species``' bark (one of :data:`SPECIES`),
    about 1 m across at 384 px."""
    if species not in SPECIES:
        raise ValueError(f"unknown bark species {species!r}; known: {', '.join(SPECIES)}")
    return SPECIES[species](np.random.default_rng(seed), (height, width))


def lower_example(species: str, height: int, width: int, seed: int) -> NDArray[np.uint8]:
    """A ``(height, width, 3)`` uint8 example of ``species``' lower-trunk bark (one of
    :data:`LOWER`), at :func:`species_example`'s scale."""
    if species not in LOWER:
        raise ValueError(f"no lower-trunk bark for {species!r}; known: {', '.join(LOWER)}")
    return LOWER[species](np.random.default_rng(seed), (height, width))
