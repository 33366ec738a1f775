"""Bark tile sets by image quilting (paper 5.2, Figures 9 to 12).

Geometry of one tile of side ``S`` (all in pixels, ``e = border + overlap``)::

    +---------------------------+   outer ``border`` ring: the class's edge patterns, exactly
    | +-----------------------+ |   next ``overlap`` band: frame or interior, split along the
    | | +-------------------+ | |       minimum-error cut (one cut per side)
    | | |     interior      | | |   inside: a patch of an example image
    | | +-------------------+ | |
    | +-----------------------+ |
    +---------------------------+

Edge patterns (one per edge colour, cut from the examples) straddle the tile edge: a
``vertical`` pattern is ``S x 2e``; the tile left of an edge of that colour shows its left
half, the tile right of it its right half, so two tiles that agree on the colour of the edge
between them continue one image across it. Horizontal patterns likewise across top and bottom
edges. Where four tiles meet, every tile shows one quadrant of the same *corner pattern*: each
edge pattern's first and last ``e`` rows are the corner pattern's, stitched onto the example
crop with the same minimum-error cut. So tiles meet without a seam along edges and at corners,
whatever their classes, as long as the colours of the edges between them agree.

Classes (paper Fig. 10; the table is :data:`schemas.tileset.CLASS_EDGES`): ``bark`` (id 1)
has vertical colour ``bark-v`` on both sides and horizontal colour ``bark-h`` on top and
bottom, so bark tiles wrap in both directions. The ``fork`` class (id 2) is a branch's first
quad ring standing upright on its crotch loop: bark colours but ``crotch-h`` at the bottom.
Around a crotch or a cap's apex the quads cannot all stand upright, so some tiles meet a
neighbour turned a quarter: those edges carry ``crotch-cw`` or ``crotch-ccw``, a vertical
pattern that on a top or bottom side is used turned a quarter (clockwise, counter-clockwise),
so it continues into the turned neighbour. One class per set of side colours that occurs
(ids 3 and up) covers them; a half turn (a side meeting the same side) never occurs.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from forest import __version__
from forest.atomic import folder_updated_when_written, write_text
from forest.bark.images import ExampleImage, read_example, write_png, write_texture_array
from forest.bark.quilting import cut_mask, min_cut_paths, squared_error
from forest.errors import ForestError, LimitError, OutputError
from schemas.tileset import (
    ARRAY_FILE,
    CLASS_EDGES,
    DEFAULT_MANIFEST,
    MANIFEST_FILE,
    MAX_UDIM_SLICES,
    QUARTER_TURN,
    SIDE_AXIS,
    UDIM_PATTERN,
    UDIM_TOKEN,
    CornerPattern,
    EdgePattern,
    SourceImage,
    TileClass,
    TileEdges,
    TileRecord,
    TileSetFiles,
    TileSetManifest,
    udim_file,
)

U8 = NDArray[np.uint8]
Progress = Callable[[str, int, int], None]  # (stage, done, total), as forest.growth.generate's
CORNER_FILE = "corner.png"
LOWER_CORNER_FILE = "corner.lower.png"
# Image quilting's patch choice: any candidate whose overlap error is within 10 % of the best
# is as good (Efros and Freeman use the same 0.1); choosing among them at random keeps tiles
# from converging on one lucky patch.
ERROR_TOLERANCE_PERCENT = 10
# When every disjoint place in the examples is taken, candidates are drawn at random and those
# whose interior overlaps earlier tiles' least (within 10 percentage points of the least) stay.
FALLBACK_CANDIDATES = 64
FALLBACK_OVERLAP_SLACK = 0.1
# Columns between the places a sliding slot's patch is tried at (build_tileset's slide).
SLIDE_STEP = 2
# Random crops an edge or corner pattern is chosen from (the most typical of them).
PATTERN_CANDIDATES = 24
# Tiles are stitched in chunks of at most this many bytes per image stack.
CHUNK_BYTES = 1 << 26
# A tile set is held in memory whole (and written as one texture array): 1 GiB of RGB bytes
# is ~1300 tiles of 512 px, far past what a bark texture array needs.
MAX_TILESET_BYTES = 1 << 30


@dataclass(frozen=True)
class TileGeometry:
    """Pixel sizes of a tile: ``size`` square, ``border`` exact ring, ``overlap`` cut band."""

    size: int
    border: int
    overlap: int

    @classmethod
    def for_size(cls, size: int) -> TileGeometry:
        """An eighth of the tile for the border and another eighth for the cut band."""
        if size < 16:
            raise ForestError(f"tile size {size} is below 16 pixels", path="--size")
        b = size // 8
        return cls(size, b, b)

    @property
    def extent(self) -> int:
        """How far the frame reaches into the tile: ``border + overlap``."""
        return self.border + self.overlap

    @property
    def corner_crop(self) -> int:
        """Side of the corner pattern's source crop: the ``2e`` junction plus an overlap
        band on every side, where the edge patterns are stitched onto it."""
        return 2 * (self.extent + self.overlap)

    @property
    def chunk(self) -> int:
        """Tiles per image stack of at most :data:`CHUNK_BYTES` (RGB)."""
        return max(1, CHUNK_BYTES // (self.size * self.size * 3))

    @property
    def region(self) -> int:
        """Side of the square of a tile where its interior patch can show: inside the border."""
        return self.size - 2 * self.border


@dataclass(frozen=True)
class ClassSpec:
    """A tile class to build: ``count`` tiles whose sides carry the colours ``edges``."""

    name: str
    id: int
    count: int
    edges: TileEdges


def default_classes(bark: int, fork: int, crotch: int = 0) -> tuple[ClassSpec, ...]:
    """Classes of :data:`schemas.tileset.DEFAULT_MANIFEST` (see the module docstring):
    ``bark`` tiles of class bark, ``fork`` of class fork and, if ``crotch`` > 0, that many of
    each crotch class. Without crotch classes a forest draws its crotch quads from the fork
    class (``forest.bark.tiles``): seams show at crotches and apexes."""
    count = {1: bark, 2: fork}
    return tuple(
        ClassSpec(c.name, c.id, count.get(c.id, crotch), CLASS_EDGES[c.id])
        for c in sorted(DEFAULT_MANIFEST.classes, key=lambda c: c.first)
        if count.get(c.id, crotch) > 0
    )


@dataclass(frozen=True, eq=False)
class TileSet:
    """A built tile set.

    tiles : (n, S, S, 3) uint8, slice order    corner : (2e, 2e, 3) uint8
    patterns : colour -> (S, 2e, 3) uint8 (vertical) or (2e, S, 3) uint8 (horizontal)
    """

    manifest: TileSetManifest
    tiles: U8
    patterns: dict[str, U8]
    corner: U8
    reused: int = 0
    """Tiles whose interior overlaps an earlier tile's in the examples, because the examples
    held no more disjoint places (see :func:`choose_patch`)."""
    lower_corner: U8 | None = None
    """The lower trunk's corner pattern (:func:`stack_lower`), like ``corner``."""


# ---------------------------------------------------------------- array functions


def band_errors(frames: U8, patches: U8, geom: TileGeometry) -> NDArray[np.integer]:
    """Error surfaces of the four overlap bands of each tile, computed on views.

    frames, patches : (n, S, S, c) uint8
    returns : (n, 4, S, o) int32, sides left, right, top, bottom; each band runs along its
    edge (rows for left and right, columns for top and bottom) and is turned so its column 0
    lies next to the border: the frame's side of the cut comes first
    """
    s, w, e, o = geom.size, geom.border, geom.extent, geom.overlap
    n = frames.shape[0]
    out = np.empty((n, 4, s, o), np.int32)
    out[:, 0] = squared_error(frames[:, :, w:e], patches[:, :, w:e])
    out[:, 1] = squared_error(frames[:, :, s - e : s - w], patches[:, :, s - e : s - w])[..., ::-1]
    out[:, 2] = squared_error(frames[:, w:e], patches[:, w:e]).transpose(0, 2, 1)
    out[:, 3] = squared_error(frames[:, s - e : s - w], patches[:, s - e : s - w]).transpose(
        0, 2, 1
    )[..., ::-1]
    return out


def compose(frames: U8, patches: U8, keep: NDArray[np.bool_], geom: TileGeometry) -> U8:
    """Tiles from their frames, interior patches and per-band masks: the patch everywhere,
    the frame over the border ring, and the frame before each cut. Only the bands are
    selected pixel by pixel; the rest are block copies.

    frames, patches : (n, S, S, c) uint8   keep : (n, 4, S, o) bool   returns : (n, S, S, c)
    """
    s, w, e = geom.size, geom.border, geom.extent
    out = patches.copy()
    for rows, cols in (
        (slice(0, w), slice(None)),
        (slice(s - w, s), slice(None)),
        (slice(w, s - w), slice(0, w)),
        (slice(w, s - w), slice(s - w, s)),
    ):
        out[:, rows, cols] = frames[:, rows, cols]
    left, right = slice(w, e), slice(s - e, s - w)
    sides = (
        (np.s_[:, :, left], keep[:, 0]),
        (np.s_[:, :, right], keep[:, 1][:, :, ::-1]),
        (np.s_[:, left, :], keep[:, 2].transpose(0, 2, 1)),
        (np.s_[:, right, :], keep[:, 3].transpose(0, 2, 1)[:, ::-1]),
    )
    for where, mask in sides:
        np.copyto(out[where], frames[where], where=mask[..., None])
    return out


def stitch_tiles(frames: U8, patches: U8, geom: TileGeometry) -> tuple[U8, NDArray[np.int64]]:
    """Stitch each interior patch into its frame along the four minimum-error cuts.

    frames, patches : (n, S, S, c) uint8 (a frame's pixels inside ``border + overlap`` are
    ignored)   returns : tiles (n, S, S, c) uint8, cuts (n, 4, S) int64 (band column per row)
    """
    cuts = min_cut_paths(band_errors(frames, geom=geom, patches=patches))
    return compose(frames, patches, cut_mask(cuts, geom.overlap), geom), cuts


def edge_patterns(strips: U8, corners: U8, geom: TileGeometry) -> U8:
    """Vertical edge patterns: example crops whose two ends are replaced by the corner pattern,
    stitched on along minimum-error cuts across the strip. (A horizontal pattern is this with
    the strip and the corner transposed, and the result transposed back.)

    strips : (m, S, 2e, c) uint8   corners : (m, 2(e+o), 2(e+o), c) uint8
    returns : (m, S, 2e, c) uint8 with rows ``[0, e)`` = corner rows ``[o+e, o+2e)`` and rows
    ``[S-e, S)`` = corner rows ``[o, o+e)``, columns ``[o, o+2e)`` of the corner in both
    """
    s, e, o = geom.size, geom.extent, geom.overlap
    cols = slice(o, o + 2 * e)
    top = corners[:, o + e : 2 * o + 2 * e, cols]  # (m, e+o, 2e, c): ends the top of the strip
    bottom = corners[:, : o + e, cols]  # (m, o+e, 2e, c): ends the bottom
    # bands across the strip, turned (m, 2e, o, c) with the corner's side first
    a = np.stack([top[:, e:], bottom[:, :o][:, ::-1]], axis=1).transpose(0, 1, 3, 2, 4)
    b = np.stack([strips[:, e : e + o], strips[:, s - e - o : s - e][:, ::-1]], axis=1).transpose(
        0, 1, 3, 2, 4
    )
    keep = cut_mask(min_cut_paths(squared_error(a, b)), o)  # (m, 2, 2e, o)
    joined = np.where(keep[..., None], a, b).transpose(0, 1, 3, 2, 4)  # (m, 2, o, 2e, c)
    out = strips.copy()
    out[:, :e] = top[:, :e]
    out[:, e : e + o] = joined[:, 0]
    out[:, s - e - o : s - e] = joined[:, 1][:, ::-1]
    out[:, s - e :] = bottom[:, o:]
    return out


def class_frame(left: U8, right: U8, top: U8, bottom: U8, geom: TileGeometry) -> U8:
    """A class's frame: the ring of width ``e`` every tile of the class starts from.

    left, right : (S, 2e, c) vertical patterns   top, bottom : (2e, S, c) horizontal patterns
    returns : (S, S, c) uint8, zero inside the ring. Corners come from the vertical patterns;
    the horizontal ones agree with them there by construction (both are the corner pattern's).
    """
    s, e = geom.size, geom.extent
    frame = np.zeros((s, s, left.shape[2]), np.uint8)
    frame[:, :e] = left[:, e:]
    frame[:, s - e :] = right[:, :e]
    frame[:e, e : s - e] = top[e:, e : s - e]
    frame[s - e :, e : s - e] = bottom[:e, e : s - e]
    return frame


# ---------------------------------------------------------------- choosing patches


@dataclass
class _Places:
    """Where interiors can come from: per example, disjoint slots of the region's size laid
    out on a jittered grid, and the regions already taken (to count overlap when slots run
    out). A slot wider than the region (``slide``) may hold its patch anywhere across it:
    ``slide`` maps the slot's leftmost place to how many columns further right it may go."""

    free: list[tuple[int, int, int]]  # (example, crop y, crop x)
    taken: list[list[tuple[int, int]]]  # per example, crop (y, x) of chosen patches
    slide: dict[tuple[int, int, int], int] = field(default_factory=dict)

    def anchor(self, place: tuple[int, int, int]) -> tuple[int, int, int]:
        """The free slot ``place`` lies in."""
        k, y, x = place
        for a in self.free:
            if a[0] == k and a[1] == y and a[2] <= x <= a[2] + self.slide.get(a, 0):
                return a
        raise KeyError(place)


def _slots(
    shapes: Sequence[tuple[int, int]], geom: TileGeometry, rng: np.random.Generator, slide: int = 0
) -> _Places:
    w, r = geom.border, geom.region
    free: list[tuple[int, int, int]] = []
    spans: dict[tuple[int, int, int], int] = {}
    for k, (h, wd) in enumerate(shapes):
        starts = []
        for extent, extra in ((h, 0), (wd, slide)):
            usable = extent - 2 * w  # the region must keep ``border`` pixels of margin
            n = max(1, usable // (r + extra)) if extra else usable // r
            edges = [w + (usable * i) // n for i in range(n + 1)]
            starts.append([(a, b - a) for a, b in itertools.pairwise(edges)])
        for y0, hy in starts[0]:
            for x0, hx in starts[1]:
                y = y0 + int(rng.integers(0, hy - r + 1)) - w
                if slide:  # the patch's place across is chosen by its error, not at random
                    x = x0 - w
                    spans[(k, y, x)] = hx - r
                else:
                    x = x0 + int(rng.integers(0, hx - r + 1)) - w
                free.append((k, y, x))
    return _Places(free=free, taken=[[] for _ in shapes], slide=spans)


def _overlap(places: _Places, k: int, y: int, x: int, r: int) -> float:
    best = 0.0
    for ty, tx in places.taken[k]:
        dy, dx = max(0, r - abs(y - ty)), max(0, r - abs(x - tx))
        best = max(best, dy * dx / (r * r))
    return best


def _candidates(
    places: _Places, shapes: Sequence[tuple[int, int]], geom: TileGeometry, rng: np.random.Generator
) -> list[tuple[int, int, int]]:
    if places.free:
        return [
            (k, y, x + d)
            for k, y, x in places.free
            for d in range(0, places.slide.get((k, y, x), 0) + 1, SLIDE_STEP)
        ]
    s = geom.size
    drawn = []
    for _ in range(FALLBACK_CANDIDATES):
        k = int(rng.integers(len(shapes)))
        h, wd = shapes[k]
        drawn.append((k, int(rng.integers(0, h - s + 1)), int(rng.integers(0, wd - s + 1))))
    scores = np.array([_overlap(places, *c, geom.region) for c in drawn])
    return [
        c
        for c, sc in zip(drawn, scores, strict=True)
        if sc <= scores.min() + FALLBACK_OVERLAP_SLACK
    ]


def _crops(examples: Sequence[U8], places: Sequence[tuple[int, int, int]], h: int, w: int) -> U8:
    return np.stack([examples[k][y : y + h, x : x + w] for k, y, x in places])


def choose_patch(
    frame: U8,
    examples: Sequence[U8],
    places: _Places,
    geom: TileGeometry,
    rng: np.random.Generator,
    scored: dict[tuple[int, int, int], int] | None = None,
) -> tuple[tuple[int, int, int], int]:
    """Image quilting's patch choice for one tile: among the candidate places, one at random
    whose overlap error against the frame is within :data:`ERROR_TOLERANCE_PERCENT` of the
    best. Candidates are the free slots, disjoint from every earlier tile's interior; once
    none is left, random places that overlap earlier interiors least.

    frame : (S, S, 3) uint8   examples : (h_k, w_k, 3) uint8 each
    scored : errors of free slots against this same frame, kept by the caller across the
        tiles of one class (a slot's error does not change; only which slots are free does)
    returns : the place ``(example, crop y, crop x)`` and its error; marks it taken
    """
    shapes = [ex.shape[:2] for ex in examples]
    from_free = bool(places.free)
    cands = _candidates(places, shapes, geom, rng)
    known = scored if scored is not None and from_free else {}
    todo = [c for c in cands if c not in known]
    s = geom.size
    step = geom.chunk
    for i in range(0, len(todo), step):
        crops = _crops(examples, todo[i : i + step], s, s)
        frames = np.broadcast_to(frame, crops.shape)
        sums = band_errors(frames, crops, geom).sum(axis=(1, 2, 3), dtype=np.int64)
        known.update(zip(todo[i : i + step], sums.tolist(), strict=True))
    err = np.array([known[c] for c in cands], np.int64)
    best = int(err.min())
    ok = np.nonzero(err * 100 <= best * (100 + ERROR_TOLERANCE_PERCENT))[0]
    pick = int(ok[rng.integers(len(ok))])
    place = cands[pick]
    if places.free:
        places.free.remove(places.anchor(place))
    places.taken[place[0]].append(place[1:])
    return place, int(err[pick])


# ---------------------------------------------------------------- building


def _check_classes(classes: Sequence[ClassSpec]) -> dict[str, str]:
    """Colour -> axis; the colours of left and right edges must be vertical, top and bottom
    horizontal, and one colour cannot be both, except a quarter-turn colour
    (:data:`schemas.tileset.QUARTER_TURN`): its pattern is vertical, turned on top and
    bottom."""
    axes: dict[str, str] = {}
    for c in classes:
        for side, axis in SIDE_AXIS.items():
            name = getattr(c.edges, side)
            if name in QUARTER_TURN:
                axis = "vertical"
            if axes.setdefault(name, axis) != axis:
                raise ForestError(
                    f"edge colour {name!r} is used on both vertical and horizontal edges",
                    path=f"classes.{c.name}.edges.{side}",
                )
    total = sum(c.count for c in classes)
    if total > MAX_UDIM_SLICES:
        raise ForestError(
            f"{total} tiles in all; UDIM names allow at most {MAX_UDIM_SLICES}", path="--per-class"
        )
    return axes


def _check_size(n: int, geom: TileGeometry) -> None:
    size = n * geom.size * geom.size * 3
    if size > MAX_TILESET_BYTES:
        raise LimitError(
            f"{n} tiles of {geom.size} px take {size / 2**30:.1f} GiB; "
            f"at most {MAX_TILESET_BYTES / 2**30:.0f} GiB",
            path="--per-class",
            limit=MAX_TILESET_BYTES,
        )


def build_tileset(
    examples: Sequence[ExampleImage],
    classes: Sequence[ClassSpec],
    geom: TileGeometry,
    seed: int,
    progress: Progress | None = None,
    slide: int = 0,
) -> TileSet:
    """Cut edge patterns and a corner pattern from the examples, then stitch an interior patch
    into every tile of every class. The same examples, classes, geometry and seed give the same
    tiles on every machine (integer errors, seeded choices). ``progress`` hears ``(stage,
    tiles done, tiles)`` as patches are chosen (``patches``), then stitched (``stitch``).

    ``corner_source`` ``(2(e+o), 2(e+o), 3)``: the corner crop to use (shared with another
    group of tiles, :func:`stack_lower`) instead of one cut here; ``corner_like``: other
    images the corner should look typical of too (that other group's examples)."""
    note = progress or (lambda stage, done, total: None)
    axes = _check_classes(classes)
    _check_size(sum(c.count for c in classes), geom)
    if not examples:
        raise ForestError("give at least one example image", path="EXAMPLE_IMAGE")
    s, e = geom.size, geom.extent
    if geom.corner_crop > s or 2 * e >= s:
        raise ForestError("border and overlap leave no interior in the tile", path="--size")
    for ex in examples:
        if ex.width < s or ex.height < s:
            raise ForestError(
                f"is {ex.width}x{ex.height} pixels, smaller than one {s}x{s} tile",
                path=str(ex.path),
            )
    rng = np.random.default_rng(seed)
    pix = [ex.pixels for ex in examples]
    n_ex = len(pix)
    target = _colour_quantiles(pix)

    # the corner pattern, then one edge pattern per colour, each from an example in turn; a
    # pattern shows in every tile of its colour, so of a few random crops the one whose
    # colours spread most like the examples' is taken: never a rare dark scar that would
    # then ring every crotch or dot every corner
    def place(
        h: int, w: int, k: int, tries: int = PATTERN_CANDIDATES, like: NDArray[np.float64] = target
    ) -> tuple[int, int, int]:
        ey, ex_ = pix[k].shape[:2]
        best: tuple[float, tuple[int, int, int]] | None = None
        for _ in range(tries):
            at = k, int(rng.integers(0, ey - h + 1)), int(rng.integers(0, ex_ - w + 1))
            q = _colour_quantiles([_crops(pix, [at], h, w)[0]])
            d = float(np.abs(q - like).sum())
            if best is None or d < best[0]:
                best = (d, at)
        assert best is not None
        return best[1]

    cs = geom.corner_crop
    # the corner shows at every tile's four corners, a grid across the bark: the plainest
    # crop of the examples' middle colour, which the eye does not pick out
    plain = np.repeat(target[:, target.shape[1] // 2 : target.shape[1] // 2 + 1], 16, axis=1)
    corner_at = place(cs, cs, int(rng.integers(n_ex)), 16 * PATTERN_CANDIDATES, plain)
    corner_src = _crops(pix, [corner_at], cs, cs)[0]
    names = sorted(axes)
    first = int(rng.integers(n_ex))
    pattern_at = {}
    for i, name in enumerate(names):
        h, w = (s, 2 * e) if axes[name] == "vertical" else (2 * e, s)
        pattern_at[name] = place(h, w, (first + i) % n_ex)
    strips = np.stack(
        [
            _crops(pix, [pattern_at[n]], s, 2 * e)[0]
            if axes[n] == "vertical"
            else _crops(pix, [pattern_at[n]], 2 * e, s)[0].transpose(1, 0, 2)
            for n in names
        ]
    )
    corners = np.stack(
        [corner_src if axes[n] == "vertical" else corner_src.transpose(1, 0, 2) for n in names]
    )
    upright = edge_patterns(strips, corners, geom)
    patterns = {
        n: np.ascontiguousarray(p if axes[n] == "vertical" else p.transpose(1, 0, 2))
        for n, p in zip(names, upright, strict=True)
    }
    o = geom.overlap
    corner = corner_src[o : o + 2 * e, o : o + 2 * e].copy()

    def across(name: str) -> U8:
        """The pattern of colour ``name`` on a top or bottom side: a quarter-turn colour's
        vertical pattern turned its quarter (np.rot90 turns counter-clockwise for k=1)."""
        turn = QUARTER_TURN.get(name)
        if turn is None:
            return patterns[name]
        return np.ascontiguousarray(np.rot90(patterns[name], k=-1 if turn == "cw" else 1))

    # every tile: a frame from its class, an interior chosen by quilting error, one stitch
    frames_by_class = {
        c.id: class_frame(
            patterns[c.edges.left],
            patterns[c.edges.right],
            across(c.edges.top),
            across(c.edges.bottom),
            geom,
        )
        for c in classes
    }
    places = _slots([p.shape[:2] for p in pix], geom, rng, slide)
    records: list[TileRecord] = []
    tile_classes: list[TileClass] = []
    chosen: list[tuple[int, int, int]] = []
    slice_class: list[int] = []
    first_slice = reused = 0
    n = sum(c.count for c in classes)
    note("patches", 0, n)
    for c in classes:
        tile_classes.append(
            TileClass(name=c.name, id=c.id, first=first_slice, count=c.count, edges=c.edges)
        )
        scored: dict[tuple[int, int, int], int] = {}
        for i in range(c.count):
            reused += not places.free
            at, err = choose_patch(frames_by_class[c.id], pix, places, geom, rng, scored)
            chosen.append(at)
            slice_class.append(c.id)
            records.append(
                TileRecord(
                    slice=first_slice + i, class_id=c.id, source=at[0], y=at[1], x=at[2], error=err
                )
            )
            note("patches", len(chosen), n)
        first_slice += c.count
    tiles = np.empty((n, s, s, 3), np.uint8)
    step = geom.chunk
    note("stitch", 0, n)
    for i in range(0, n, step):
        frames = np.stack([frames_by_class[cid] for cid in slice_class[i : i + step]])
        patches = _crops(pix, chosen[i : i + step], s, s)
        tiles[i : i + step] = stitch_tiles(frames, patches, geom)[0]
        note("stitch", min(i + step, n), n)

    manifest = TileSetManifest(
        classes=tile_classes,
        tile_size=s,
        border=geom.border,
        overlap=geom.overlap,
        seed=seed,
        generator=f"interlocking-forest {__version__}",
        sources=[
            SourceImage(
                file=ex.path.name,
                sha256=ex.sha256,
                width=ex.width,
                height=ex.height,
                channels=ex.channels,
                format=ex.format,
            )
            for ex in examples
        ],
        edge_patterns=[
            EdgePattern(
                name=name,
                axis=axes[name],
                file=f"edge.{name}.png",
                source=pattern_at[name][0],
                y=pattern_at[name][1],
                x=pattern_at[name][2],
            )
            for name in names
        ],
        corner=CornerPattern(
            file=CORNER_FILE, source=corner_at[0], y=corner_at[1], x=corner_at[2], size=cs
        ),
        tiles=records,
        files=TileSetFiles(
            udim=UDIM_PATTERN,
            slices=[udim_file(UDIM_PATTERN, k) for k in range(n)],
            array=ARRAY_FILE,
        ),
    )
    return TileSet(
        manifest=manifest,
        tiles=tiles,
        patterns=patterns,
        corner=corner,
        reused=reused,
    )


def _colour_quantiles(images: Sequence[U8]) -> NDArray[np.float64]:
    """``(3, 16)`` 16 quantiles of each colour channel over all ``images``, from the 10th
    to the 90th percentile: a crop matches them whatever it holds of a feature rarer than
    a tenth of the examples, but not if such a feature fills a tenth of the crop."""
    px = np.concatenate([im.reshape(-1, im.shape[-1]) for im in images]).astype(np.float64)
    return np.quantile(px, np.linspace(0.1, 0.9, 16), axis=0).T


LOWER_ID = 100
"""A lower-trunk class's id is this plus the id of the class it stands for."""
LOWER_PREFIX = "lower-"
"""Names and edge colours of the lower trunk's classes: their own, so the lower bark
continues only into itself."""


def lower_classes(classes: Sequence[ClassSpec]) -> tuple[ClassSpec, ...]:
    """The lower trunk's classes for ``classes``: the same counts, ids :data:`LOWER_ID` up,
    names and edge colours prefixed :data:`LOWER_PREFIX`."""

    def rename(e: TileEdges) -> TileEdges:
        return TileEdges(**{k: LOWER_PREFIX + v for k, v in e.model_dump().items()})

    return tuple(
        ClassSpec(LOWER_PREFIX + c.name, LOWER_ID + c.id, c.count, rename(c.edges)) for c in classes
    )


def stack_lower(upper: TileSet, lower: TileSet, fraction: float) -> TileSet:
    """One tile set of two groups: ``upper``'s slices, then ``lower``'s (built with
    :func:`lower_classes`: its own edge colours and corner pattern, so it meets only itself
    without a seam), whose classes stand for the classes of ``upper`` they were made for on
    trunk pieces below ``fraction`` of the tree's height (``TileSetManifest.lower_trunk``)."""
    um, lm = upper.manifest, lower.manifest
    assert um.files is not None and um.corner is not None and lm.corner is not None
    n_up, n_src = um.n_slices, len(um.sources)
    classes = [
        *um.classes,
        *(
            c.model_copy(update={"first": c.first + n_up, "stands_for": c.id - LOWER_ID})
            for c in lm.classes
        ),
    ]
    n = n_up + lm.n_slices
    manifest = um.model_copy(
        update={
            "classes": classes,
            "sources": [*um.sources, *lm.sources],
            "edge_patterns": [
                *um.edge_patterns,
                *(p.model_copy(update={"source": p.source + n_src}) for p in lm.edge_patterns),
            ],
            "tiles": [
                *um.tiles,
                *(
                    t.model_copy(update={"slice": t.slice + n_up, "source": t.source + n_src})
                    for t in lm.tiles
                ),
            ],
            "files": um.files.model_copy(
                update={"slices": [udim_file(um.files.udim, k) for k in range(n)]}
            ),
            "lower_trunk": fraction,
            "lower_corner": lm.corner.model_copy(
                update={"file": LOWER_CORNER_FILE, "source": lm.corner.source + n_src}
            ),
        }
    )
    manifest = TileSetManifest.model_validate(manifest.model_dump())  # validated whole
    return TileSet(
        manifest=manifest,
        tiles=np.concatenate([upper.tiles, lower.tiles]),
        patterns={**upper.patterns, **lower.patterns},
        corner=upper.corner,
        reused=upper.reused + lower.reused,
        lower_corner=lower.corner,
    )


# the slice files of any earlier set written with the default names
_UDIM_FILE = re.compile(re.escape(UDIM_PATTERN).replace(re.escape(UDIM_TOKEN), r"1\d{3}"))


def write_tileset(tileset: TileSet, folder: Path, progress: Progress | None = None) -> list[Path]:
    """Write the slices (``bark.<UDIM>.png``), the texture array, the edge and corner patterns
    and, last, ``manifest.json``; remove ``bark.<UDIM>.png`` files of an earlier, larger set.
    Every file is written into a private staging folder first and renamed into ``folder``
    only once all are complete, so a failed write leaves the old set whole. Returns the files
    written. ``progress`` hears ``("write", images written, images)``: the slices, then the
    texture array."""
    note = progress or (lambda stage, done, total: None)
    m = tileset.manifest
    assert m.files is not None and m.corner is not None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create folder: {exc.strerror}", path=str(folder)) from None
    with folder_updated_when_written(folder, last=[MANIFEST_FILE]) as staging:
        names = list(m.files.slices)
        images = len(names) + bool(m.files.array)  # the edge and corner patterns are small
        note("write", 0, images)
        for k, (name, t) in enumerate(zip(m.files.slices, tileset.tiles, strict=True)):
            write_png(staging / name, t)
            note("write", k + 1, images)
        if m.files.array:
            names.append(m.files.array)
            write_texture_array(staging / m.files.array, tileset.tiles)
            note("write", images, images)
        for p in m.edge_patterns:
            names.append(p.file)
            write_png(staging / p.file, tileset.patterns[p.name])
        names.append(m.corner.file)
        write_png(staging / m.corner.file, tileset.corner)
        if m.lower_corner is not None:
            assert tileset.lower_corner is not None
            names.append(m.lower_corner.file)
            write_png(staging / m.lower_corner.file, tileset.lower_corner)
        names.append(MANIFEST_FILE)
        write_text(staging / MANIFEST_FILE, m.model_dump_json(indent=2) + "\n")
    keep = set(m.files.slices)
    for old in folder.iterdir():
        if _UDIM_FILE.fullmatch(old.name) and old.name not in keep:
            old.unlink()
    return [folder / name for name in names]


def make_tileset(
    paths: Sequence[Path],
    folder: Path,
    classes: Sequence[ClassSpec],
    size: int,
    seed: int,
    progress: Progress | None = None,
) -> TileSet:
    """``forest tiles``: read the examples, build ``classes``, write the set into
    ``folder`` (``progress``: see :func:`build_tileset` and :func:`write_tileset`)."""
    geom = TileGeometry.for_size(size)
    _check_classes(classes)
    _check_size(sum(c.count for c in classes), geom)
    examples = [read_example(Path(p), min_size=size) for p in paths]
    tileset = build_tileset(examples, classes, geom, seed, progress)
    write_tileset(tileset, folder, progress)
    return tileset
