"""Tile-set manifest (paper 5.1, 5.2): which texture-array slices belong to which tile class,
and, for a tile set built by ``forest tiles``, how it was made: the edge pattern of every edge
colour, the source images (with checksums), the seed, the tile geometry and the file names.

Image orientation throughout: row 0 is the top of a tile, column 0 its left. On a quad, u runs
left to right (around the tube) and v bottom to top (along it), so a tile's ``bottom`` edge is
the quad's v = 0 edge.
"""

from __future__ import annotations

import itertools
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from schemas.base import StrictModel

ColourName = Annotated[str, Field(pattern=r"^[a-z0-9][a-z0-9_-]{0,31}$")]
"""An edge colour (paper Fig. 9): tiles match along an edge when both sides name it."""
FileName = Annotated[str, Field(pattern=r"^[^/\\]+$", min_length=1, max_length=255)]
"""A file in the tile-set folder (no folders in the name)."""
Sha256 = Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]
Pixels = Annotated[int, Field(ge=0)]
UDIM_TOKEN = "<UDIM>"
UDIM_PATTERN = "bark.<UDIM>.png"  # the default slice files
ARRAY_FILE = "bark_array.tif"  # the texture array a written tile set carries
MANIFEST_FILE = "manifest.json"
SIDE_AXIS = {"left": "vertical", "right": "vertical", "top": "horizontal", "bottom": "horizontal"}
"""The edge-pattern axis each side of a tile takes."""
BARK_V, BARK_H = "bark-v", "bark-h"
"""Bark colours: every edge where two upright tiles meet."""
CROTCH_V, CROTCH_H = "crotch-v", "crotch-h"
"""A branch's crotch loop, where upright tiles meet across it."""
CROTCH_CW, CROTCH_CCW = "crotch-cw", "crotch-ccw"
"""Quarter-turn colours: where a tile meets a neighbour turned 90 degrees (around a crotch or
a cap's apex the mesh cannot be one upright grid). Their pattern is vertical and, on top and
bottom sides, is used turned a quarter: clockwise for ``-cw`` (so a tile's left side meets
its neighbour's bottom, or its right side the neighbour's top), counter-clockwise for
``-ccw`` (left meets top, right meets bottom)."""
QUARTER_TURN = {CROTCH_CW: "cw", CROTCH_CCW: "ccw"}
"""Quarter-turn colour -> the turn of its pattern on top and bottom sides."""
MAX_UDIM_SLICES = 999
"""UDIM tiles run from 1001 to 1999 (ten columns, a hundred rows)."""


class TileEdges(StrictModel):
    """The edge colour of each side of the tiles of a class. Left and right edges take
    ``vertical`` edge patterns, top and bottom ``horizontal`` ones."""

    left: ColourName
    right: ColourName
    top: ColourName
    bottom: ColourName


class TileClass(StrictModel):
    name: Annotated[str, Field(min_length=1, max_length=64)]
    id: Annotated[int, Field(ge=1, le=255)]
    """The tile class a quad carries (1 bark, 2 fork region)."""
    first: Annotated[int, Field(ge=0)]
    """First texture-array slice (also UDIM tile ``1001 + slice``) of this class."""
    count: Annotated[int, Field(ge=1, le=4096)]
    edges: TileEdges | None = None
    """Edge colours of this class's tiles (absent in a manifest written by hand)."""
    stands_for: Annotated[int, Field(ge=1, le=255)] | None = None
    """On a trunk piece that starts below the manifest's ``lower_trunk`` fraction of its
    tree's height, quads of class ``stands_for`` draw from this class instead: the lower
    trunk's own bark (pine's grey fissures under the orange plates, birch's black foot)."""


class SourceImage(StrictModel):
    """An example image the tile set was cut from."""

    file: Annotated[str, Field(min_length=1, max_length=255)]
    """The file's name (without its folder)."""
    sha256: Sha256
    """Checksum of the file's bytes."""
    width: Annotated[int, Field(ge=1)]
    height: Annotated[int, Field(ge=1)]
    channels: Literal[1, 3]
    format: Annotated[str, Field(min_length=1, max_length=16)]
    """Pixel type in the file: ``uint8``, ``uint16``, ``half``, ``float``..."""


class _Crop(StrictModel):
    source: Annotated[int, Field(ge=0)]
    """Index into ``sources``."""
    x: Pixels
    """Left column of the crop in the source image."""
    y: Pixels
    """Top row of the crop in the source image."""


class EdgePattern(_Crop):
    """The image straddling every edge of one colour (paper 5.2: one per edge colour).

    A ``vertical`` pattern is ``tile_size`` rows by ``2 * (border + overlap)`` columns and runs
    along left and right edges: the tile left of such an edge shows the pattern's left half
    in its rightmost columns, the tile right of it the right half in its leftmost columns, so
    the two meet without a seam. A ``horizontal`` pattern is the same turned a quarter: its
    top half ends the tile above, its bottom half starts the tile below. Only the ``border``
    columns (rows) next to the edge are guaranteed in every tile; further in, the tile's
    interior takes over along a minimum-error cut. The first and last ``border + overlap``
    pixels along the edge are the corner pattern's, so all tiles agree at their corners.
    """

    name: ColourName
    axis: Literal["vertical", "horizontal"]
    file: FileName


class CornerPattern(_Crop):
    """Where four tiles meet: ``file`` holds the ``2 * (border + overlap)`` square around a
    tile corner (its top-left quadrant ends the tile up-left of the corner). ``size`` is the
    side of the crop taken from the source, which is larger by ``overlap`` on every side."""

    file: FileName
    size: Annotated[int, Field(ge=2)]


class TileRecord(_Crop):
    """Where one tile's interior came from."""

    slice: Pixels
    class_id: Annotated[int, Field(ge=1, le=255)]
    error: Annotated[int, Field(ge=0)]
    """Sum of squared 8-bit differences between the interior patch and the tile's frame over
    the overlap bands, before the cut (image quilting's patch-selection error)."""


class TileSetFiles(StrictModel):
    udim: Annotated[str, Field(pattern=r"^[^/\\]*<UDIM>[^/\\]*$")] = UDIM_PATTERN
    """File-name pattern of the per-slice images: slice ``k`` is UDIM tile ``1001 + k``."""
    slices: list[FileName]
    """One image per texture-array slice, in slice order."""
    array: FileName | None = None
    """The texture array in one file (a TIFF with one subimage per slice, in slice order)."""


class TileSetManifest(BaseModel):
    model_config = ConfigDict(extra="allow", frozen=True)

    classes: Annotated[list[TileClass], Field(min_length=1)]
    tile_size: Annotated[int, Field(ge=2, le=4096)] | None = None
    """Width and height of every tile, pixels."""
    border: Annotated[int, Field(ge=1)] | None = None
    """Width of the strip along each edge that equals the edge pattern exactly."""
    overlap: Annotated[int, Field(ge=1)] | None = None
    """Width of the band next to the border where the cut to the interior runs."""
    seed: Annotated[int, Field(ge=0)] | None = None
    generator: Annotated[str, Field(max_length=64)] | None = None
    """What built the set, with its version (``interlocking-forest 0.1.0``)."""
    sources: list[SourceImage] = []
    edge_patterns: list[EdgePattern] = []
    corner: CornerPattern | None = None
    tiles: list[TileRecord] = []
    files: TileSetFiles | None = None
    lower_trunk: Annotated[float, Field(gt=0.0, le=1.0)] | None = None
    """Height fraction of a tree below which its trunk pieces take the classes that stand
    for theirs (``TileClass.stands_for``); absent: one bark from root to top."""
    lower_corner: CornerPattern | None = None
    """The corner pattern of the classes that stand for others (they have edge colours of
    their own and meet only each other); ``corner`` is the rest's."""

    @model_validator(mode="after")
    def _lower_trunk(self) -> TileSetManifest:
        ids = {c.id: c for c in self.classes}
        lower = [c for c in self.classes if c.stands_for is not None]
        if lower and self.lower_trunk is None:
            raise ValueError("classes stand for others but lower_trunk is not given")
        for c in lower:
            target = ids.get(c.stands_for)  # type: ignore[arg-type]
            if target is None or target.stands_for is not None:
                raise ValueError(f"class {c.name} stands for {c.stands_for}, not a plain class")
        if len({c.stands_for for c in lower}) != len(lower):
            raise ValueError("two classes stand for the same class")
        return self

    @model_validator(mode="after")
    def _disjoint(self) -> TileSetManifest:
        ids = [c.id for c in self.classes]
        if len(set(ids)) != len(ids):
            raise ValueError(f"tile class ids repeat: {ids}")
        spans = sorted((c.first, c.first + c.count) for c in self.classes)
        for (_, end), (start, _) in itertools.pairwise(spans):
            if start < end:
                raise ValueError("tile class slice ranges overlap")
        return self

    @model_validator(mode="after")
    def _references(self) -> TileSetManifest:
        axis = {p.name: p.axis for p in self.edge_patterns}
        if len(axis) != len(self.edge_patterns):
            raise ValueError("edge pattern names repeat")
        for c in self.classes:
            if c.edges is None:
                continue
            for side, want in SIDE_AXIS.items():
                name = getattr(c.edges, side)
                if name not in axis:
                    raise ValueError(f"class {c.name}: {side} edge colour {name!r} has no pattern")
                if name in QUARTER_TURN:  # a vertical pattern, turned on top and bottom
                    want = "vertical"
                if axis[name] != want:
                    raise ValueError(
                        f"class {c.name}: {side} edge colour {name!r} is {axis[name]}, not {want}"
                    )
        crops: list[_Crop] = [*self.edge_patterns, *self.tiles]
        crops += [c for c in (self.corner, self.lower_corner) if c is not None]
        for crop in crops:
            if crop.source >= len(self.sources):
                raise ValueError(f"source {crop.source} is not in sources")
        by_id = {c.id: c for c in self.classes}
        for t in self.tiles:
            cls = by_id.get(t.class_id)
            if cls is None or not cls.first <= t.slice < cls.first + cls.count:
                raise ValueError(f"tile of slice {t.slice} is not in class {t.class_id}")
        if self.files is not None and len(self.files.slices) != self.n_slices:
            raise ValueError(
                f"files.slices names {len(self.files.slices)} images for {self.n_slices} slices"
            )
        if self.files is not None and self.n_slices > MAX_UDIM_SLICES:
            raise ValueError(f"{self.n_slices} slices; UDIM tiles 1001-1999 hold {MAX_UDIM_SLICES}")
        size, border, overlap = self.tile_size, self.border, self.overlap
        known = size is not None and border is not None and overlap is not None
        if known and 2 * (border + overlap) >= size:  # type: ignore[operator]
            raise ValueError("border and overlap leave no interior in the tile")
        return self

    @property
    def n_slices(self) -> int:
        return max(c.first + c.count for c in self.classes)


def udim_file(pattern: str, slice_index: int) -> str:
    """The file of one slice: ``bark.<UDIM>.png`` and slice ``k`` give ``bark.{1001+k}.png``."""
    return pattern.replace(UDIM_TOKEN, str(1001 + slice_index))


def _edges(left: str, right: str, top: str, bottom: str) -> TileEdges:
    return TileEdges(left=left, right=right, top=top, bottom=bottom)


_LETTER = {BARK_V: "b", BARK_H: "b", CROTCH_V: "c", CROTCH_H: "c", CROTCH_CW: "r", CROTCH_CCW: "l"}
_CROTCH_EDGES = [
    # (left, right, top, bottom): every side set the pieces' crotches and apexes need
    # (forest.geometry.pieces assigns them; a test checks each shared edge's two sides agree)
    (BARK_V, BARK_V, BARK_H, CROTCH_CCW),
    (BARK_V, BARK_V, BARK_H, CROTCH_CW),
    (BARK_V, BARK_V, CROTCH_CW, BARK_H),
    (BARK_V, BARK_V, CROTCH_H, BARK_H),
    (BARK_V, CROTCH_CCW, BARK_H, BARK_H),
    (BARK_V, CROTCH_CCW, BARK_H, CROTCH_CW),
    (BARK_V, CROTCH_CCW, BARK_H, CROTCH_H),
    (CROTCH_CCW, BARK_V, BARK_H, CROTCH_CCW),
    (CROTCH_CCW, BARK_V, BARK_H, CROTCH_H),
    (CROTCH_CCW, CROTCH_CW, CROTCH_CCW, BARK_H),
    (CROTCH_CW, BARK_V, BARK_H, BARK_H),
    (CROTCH_CW, CROTCH_CCW, BARK_H, BARK_H),
    (CROTCH_CW, CROTCH_CCW, BARK_H, CROTCH_CCW),
    (CROTCH_CW, CROTCH_CCW, CROTCH_CCW, BARK_H),
    (CROTCH_CW, CROTCH_CCW, CROTCH_CCW, CROTCH_CCW),
]
CROTCH_TILES = 1
"""Tiles per crotch class in the default manifest."""
CLASS_EDGES: dict[int, TileEdges] = {
    1: _edges(BARK_V, BARK_V, BARK_H, BARK_H),
    2: _edges(BARK_V, BARK_V, BARK_H, CROTCH_H),
    **{3 + k: _edges(*e) for k, e in enumerate(_CROTCH_EDGES)},
}
"""Edge colours of the default classes by id: the colours every piece's quads are laid out
for (``forest.geometry.pieces``), and what ``forest tiles`` builds them with."""

DEFAULT_MANIFEST = TileSetManifest(
    classes=[
        TileClass(name="bark", id=1, first=0, count=8),
        TileClass(name="fork", id=2, first=8, count=4),
        *(
            TileClass(
                # named by the sides' colours, left right top bottom: b bark, c crotch,
                # r and l the clockwise and counter-clockwise quarter-turn colours
                name="crotch-" + "".join(_LETTER[e] for e in edges),
                id=3 + k,
                first=12 + CROTCH_TILES * k,
                count=CROTCH_TILES,
            )
            for k, edges in enumerate(_CROTCH_EDGES)
        ),
    ]
)
"""The classes every piece's quads use (edges in :data:`CLASS_EDGES`): bark, fork (the
first ring of a branch, upright on its crotch loop) and one class per set of side colours
around a crotch or a cap's apex."""
