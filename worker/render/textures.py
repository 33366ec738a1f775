"""The bark texture array (paper 5.1): one slice per tile, addressed by the tile index.

The slices are the tile set the scene uses (:func:`forest.bark.tile_folder.scene_tile_images`:
a given folder, the one the scene's material names, or the shipped set its grammar names),
else a procedural placeholder made here in numpy, with one slice per tile of the scene's
manifest (at least max tile index + 1). The placeholder's slices share one periodic border
pattern and differ only inside, so neighbouring quads meet without seams, as the paper's
tiles do.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from forest.bark.tile_folder import TileImages, scene_tile_images
from schemas.tileset import TileSetManifest

if TYPE_CHECKING:
    import moderngl

PLACEHOLDER_SIZE = 64
BARK_RGB = np.array([0.50, 0.36, 0.24])
FORK_RGB = np.array([0.46, 0.38, 0.26])


def _fade(x: NDArray[np.float64], width: float = 0.2) -> NDArray[np.float64]:
    """0 at the border, 1 from ``width`` inwards (smoothstep)."""
    t = np.clip(x / width, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def procedural_tiles(
    manifest: TileSetManifest, n_slices: int, size: int = PLACEHOLDER_SIZE, seed: int = 0
) -> TileImages:
    """Placeholder bark: a border pattern periodic in u and v shared by every slice, plus
    per-slice grooves and blotches that fade to nothing at the border."""
    u, v = np.meshgrid((np.arange(size) + 0.5) / size, (np.arange(size) + 0.5) / size)
    v = v[::-1]  # row 0 is the top of the image (v = 1)
    tau = 2 * np.pi
    base = (
        0.5
        + 0.22 * np.sin(tau * (3 * u + 0.35 * np.sin(tau * v)))
        + 0.08 * np.sin(tau * 7 * u) * np.sin(tau * 2 * v)
    )
    window = _fade(u) * _fade(1 - u) * _fade(v) * _fade(1 - v)
    tint = np.broadcast_to(BARK_RGB, (n_slices, 3)).copy()
    for c in manifest.classes:
        if c.name != "bark" and c.first < n_slices:
            tint[c.first : c.first + c.count] = FORK_RGB
    rng = np.random.default_rng(seed)
    out = np.empty((n_slices, size, size, 4), np.uint8)
    for k in range(n_slices):
        inside = np.zeros_like(u)
        for _ in range(4):  # smooth blotches: integer frequencies, random phases
            fx, fy = rng.integers(1, 5, size=2)
            inside += 0.12 * np.sin(tau * (fx * u + fy * v) + rng.uniform(0, tau))
        for u0 in rng.uniform(0.15, 0.85, size=rng.integers(1, 4)):  # dark vertical grooves
            wobble = 0.03 * np.sin(tau * (v + rng.uniform()))
            inside -= 0.45 * np.exp(-(((u - u0 - wobble) / 0.035) ** 2))
        value = np.clip(base + window * inside, 0.0, 1.0)
        rgb = tint[k] * (0.45 + 1.1 * value[..., None])
        out[k, ..., :3] = np.clip(rgb * 255 + 0.5, 0, 255).astype(np.uint8)
        out[k, ..., 3] = 255
    return TileImages(out, f"procedural placeholder ({n_slices} slices)")


def tile_images(
    manifest: TileSetManifest,
    folder: Path | None = None,
    scene_folder: Path | None = None,
    shipped: bool = True,
    bark: str = "default",
) -> TileImages:
    """The scene's ``manifest.n_slices`` slices: the tile set
    :func:`~forest.bark.tile_folder.scene_tile_images` finds (``folder``, else the scene's
    ``scene_folder`` if it exists, else the shipped set ``bark`` with ``shipped``), else the
    procedural placeholder."""
    found = scene_tile_images(manifest, folder, scene_folder, shipped, bark)
    return procedural_tiles(manifest, manifest.n_slices) if found is None else found


def upload(ctx: moderngl.Context, images: TileImages) -> moderngl.TextureArray:
    """A mipmapped RGBA8 texture array; GL rows go bottom-up, so each slice is flipped."""
    import moderngl

    n, h, w, _ = images.slices.shape
    data = np.ascontiguousarray(images.slices[:, ::-1])
    tex = ctx.texture_array((w, h, n), 4, data.tobytes())
    tex.repeat_x = False  # a tile belongs to one quad: clamp, never bleed the opposite border
    tex.repeat_y = False
    tex.build_mipmaps()
    tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
    return tex
