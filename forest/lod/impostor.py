"""The farthest level: an octahedral impostor of a tree, baked from its LOD0 meshes with
:func:`forest.lod.views.draw_views` (the render extra's GL).

* The atlas: ``frames x frames`` orthographic views from directions on a hemi-octahedral grid
  (the upper half of the sphere folded flat: cell (i, j) looks from the direction its centre
  decodes to), each ``px`` square, albedo with alpha, world normals and depth, for an engine's
  octahedral impostor shader, which blends the nearest frames by the view direction.
* The card pair: two upright crossed cards (4 triangles) showing the views from +z and +x,
  cropped to the tree: what a DCC or an engine without such a shader shows at a distance.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np
from numpy.typing import NDArray

from forest.geometry.transforms import F64
from forest.lod.select import BarkMesh, LeavesMesh
from forest.lod.views import GL_VERSION, Views, draw_views

if TYPE_CHECKING:
    from forest.growth.foliage import FoliageAnchors
    from forest.growth.generate import Forest

G = TypeVar("G", bound=np.generic)
FRAMES = 4  # atlas frames per side: 16 views of the upper hemisphere
FRAME_PX = 128
CARD_PX = 256
CARD_DIRECTIONS = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])  # the crossed cards' normals


def hemi_octahedral_directions(frames: int) -> F64:
    """``(frames * frames, 3)`` unit directions (y >= 0) at the cell centres of a
    hemi-octahedral grid, row-major (row = the second grid coordinate)."""
    c = (np.arange(frames) + 0.5) / frames * 2.0 - 1.0
    u, v = np.meshgrid(c, c)
    x, z = (u + v) / 2.0, (u - v) / 2.0
    d = np.stack([x, 1.0 - np.abs(x) - np.abs(z), z], axis=-1).reshape(-1, 3)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@dataclass(frozen=True, eq=False)
class Impostor:
    """albedo (F p, F p, 4), normal (F p, F p, 3) uint8 and depth (F p, F p) float32: the
    atlas of ``frames`` x ``frames`` views; cards (c, 2 c, 4) uint8: the views from +z (left
    half) and +x (right half); centre and radius of the sphere every view frames (tree
    space)."""

    albedo: NDArray[np.uint8]
    normal: NDArray[np.uint8]
    depth: NDArray[np.float32]
    cards: NDArray[np.uint8]
    centre: F64
    radius: float
    frames: int


def _tile(views: NDArray[G], frames: int) -> NDArray[G]:
    """``(F F, p, p, ...)`` -> ``(F p, F p, ...)``, frame (i, j) at row i, column j."""
    p = views.shape[1]
    rest = views.shape[3:]
    grid = views.reshape(frames, frames, p, p, *rest).swapaxes(1, 2)
    return np.ascontiguousarray(grid.reshape(frames * p, frames * p, *rest))


def bake_impostor(
    bark: BarkMesh,
    leaves: LeavesMesh | None,
    leaf_picture: NDArray[np.uint8],
    bark_colour: tuple[float, float, float],
    frames: int = FRAMES,
    px: int = FRAME_PX,
    card_px: int = CARD_PX,
) -> Impostor:
    """The tree's (LOD0's ``bark`` and ``leaves``) :class:`Impostor`."""
    from forest.gl.context import create_context

    # both passes in one context: making an EGL context is 20-35 ms of a one-tree run
    ctx = create_context(GL_VERSION)
    try:
        atlas = draw_views(
            bark, leaves, leaf_picture, hemi_octahedral_directions(frames), px, bark_colour,
            context=ctx,
        )  # fmt: skip
        cards: Views = draw_views(
            bark,
            leaves,
            leaf_picture,
            CARD_DIRECTIONS,
            card_px,
            bark_colour,
            centre=atlas.centre,
            radius=atlas.radius,
            context=ctx,
        )
    finally:
        ctx.release()
    return Impostor(
        _tile(atlas.albedo, frames),
        _tile(atlas.normal, frames),
        _tile(atlas.depth, frames),
        np.ascontiguousarray(np.concatenate(list(cards.albedo), axis=1)),
        atlas.centre,
        atlas.radius,
        frames,
    )


def bake_tree_impostor(
    forest: Forest, anchors: FoliageAnchors | None, bark: BarkMesh, leaves: LeavesMesh | None
) -> Impostor:
    """A tree's impostor from its full meshes ``bark`` and ``leaves`` in its species' leaf
    picture and bark colour: USD's lod3 and glTF's LOD3 alike."""
    from forest.bark.tilesets import mean_colour
    from forest.growth.foliage import leaf_texture

    family = "broadleaf" if anchors is None else anchors.family
    return bake_impostor(bark, leaves, leaf_texture(family), mean_colour(forest.grammar.bark))


def card_pair(imp: Impostor) -> tuple[F64, F64, NDArray[np.int32], F64]:
    """The two crossed cards, each cropped to its picture's opaque pixels: points (8, 3),
    normals (8, 3), quads (2, 4), vertex st (8, 2) into :attr:`Impostor.cards`."""
    c, r = imp.centre, imp.radius
    size = imp.cards.shape[0]
    pts, nrm, st = [], [], []
    # per card: its picture's right and normal (the view's own frame, as draw_views sets it)
    frames = [
        (np.array([1.0, 0.0, 0.0]), CARD_DIRECTIONS[0]),
        (np.array([0.0, 0.0, -1.0]), CARD_DIRECTIONS[1]),
    ]
    for k, (right, normal) in enumerate(frames):
        alpha = imp.cards[:, k * size : (k + 1) * size, 3] > 0
        rows, cols = np.flatnonzero(alpha.any(axis=1)), np.flatnonzero(alpha.any(axis=0))
        if not len(rows):
            rows = cols = np.array([0, size - 1])
        # picture fractions: a from the left, b from the bottom (row 0 is the top)
        a0, a1 = cols[0] / size, (cols[-1] + 1) / size
        b0, b1 = 1.0 - (rows[-1] + 1) / size, 1.0 - rows[0] / size
        for a, b in ((a0, b0), (a1, b0), (a1, b1), (a0, b1)):
            pts.append(c + right * (2 * a - 1) * r + np.array([0.0, 1.0, 0.0]) * (2 * b - 1) * r)
            nrm.append(normal)
            st.append(((k + a) / 2.0, b))
    return (
        np.array(pts),
        np.array(nrm),
        np.arange(8, dtype=np.int32).reshape(2, 4),
        np.array(st),
    )


@functools.cache
def gl_missing() -> str | None:
    """Why no impostor can be baked here (no moderngl, no EGL: the render extra is not
    installed), or None where it can. Asked once per process: each try makes and drops a GL
    context, and a write asks several times (the writer, the CLI's note)."""
    from forest.errors import ForestError

    try:
        from forest.gl.context import create_context

        create_context(GL_VERSION).release()
    except (ImportError, ForestError) as exc:
        return str(exc)
    return None


def write_impostor(imp: Impostor, folder: Path, stem: str) -> dict[str, Path]:
    """The impostor's pictures as PNGs in ``folder``: ``<stem>.albedo.png`` (sRGB with
    alpha), ``<stem>.normal.png`` (world normal, 0.5 + 0.5 n), ``<stem>.depth.png`` (grey,
    255 nearest the camera, 0 where nothing is) and ``<stem>.cards.png``; by kind."""
    from forest.bark.images import write_png

    folder.mkdir(parents=True, exist_ok=True)
    near = np.round((1.0 - imp.depth) * 255.0).astype(np.uint8)
    out = {
        "albedo": imp.albedo,
        "normal": imp.normal,
        "depth": near[..., None],
        "cards": imp.cards,
    }
    return {
        kind: write_png(folder / f"{stem}.{kind}.png", np.ascontiguousarray(pixels))
        for kind, pixels in out.items()
    }
