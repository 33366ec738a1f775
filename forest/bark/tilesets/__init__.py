"""Tile sets shipped with the package, one folder per name in :data:`SETS`.

Each is 8 bark, 4 fork and 1 of each crotch class, tiles of 128 px (the classes of
:data:`schemas.tileset.DEFAULT_MANIFEST`: rebuild after classes are added there), quilted
from two procedural bark examples of 512 x 768 px (seeds 1 and 2; each tile's interior placed
across its slot where it fits its frame best, ``SLIDE``), tile-set seed 7:

- ``default/``: furrowed bark from :func:`forest.bark.barkgen.bark_example`;
- ``<species>/`` for each of :data:`forest.bark.barkgen.SPECIES` (oak, almond, birch, pine,
  spruce, willow, poplar, hazel): that species' bark from
  :func:`forest.bark.barkgen.species_example`.

Pine and birch add the lower trunk's own bark (:data:`LOWER_TRUNK`): 8 bark and 4 fork tiles
more (slices 27 to 38), quilted from two examples of :func:`forest.bark.barkgen.lower_example`
with edge and corner patterns of their own (``corner.lower.png``), whose classes stand for bark
and fork on trunk pieces below that fraction of the tree's height (the manifest's
``lower_trunk``; crotches there keep the upper classes).

A grammar names its set in ``bark``. Rebuild them all with ``python -m forest.bark.tilesets``
after changing the quilting, the bark generators or the manifest's classes; a test fails while
the shipped files differ from what the code makes.
"""

from __future__ import annotations

import functools
import json
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from forest.bark.barkgen import SPECIES, bark_example, lower_example, species_example
from schemas.tileset import CLASS_EDGES, DEFAULT_MANIFEST, TileSetManifest

if TYPE_CHECKING:  # the image and quilting modules load OpenImageIO: only when building
    from collections.abc import Callable

    from forest.bark.images import ExampleImage
    from forest.bark.tileset import ClassSpec, TileSet

DEFAULT_SET = "default"
MEAN_COLOUR_FILE = "mean_colour.json"
"""Beside a shipped set's tiles: its :func:`mean_colour`, ``[r, g, b]`` linear."""
SETS: tuple[str, ...] = (DEFAULT_SET, *SPECIES)
"""Names of the shipped tile sets (the values a grammar's ``bark`` may take)."""
DEFAULT_TILE_SIZE = 128
DEFAULT_SEED = 7
EXAMPLE_SIZE = 512  # tall: 5 rows of disjoint interiors of 96 px
EXAMPLE_WIDTH = 768  # wide: 5 slots of 147 px, where an interior slides 51 px (SLIDE)
SLIDE = 48  # (25 slots per example: 50 for 27 tiles)
EXAMPLE_SEEDS = (1, 2)
LOWER_TRUNK = {"pine": 0.33, "birch": 0.15}
"""Sets with a lower trunk of their own: the height fraction it reaches (Scots pine: grey-brown
and fissured below about a third; silver birch: a black fissured foot)."""
LOWER_CLASSES = ("bark", "fork")  # the lower trunk's classes: crotches keep the upper ones
# a class the manifest gives no edges takes the default colouring of its id (the colours the
# pieces are laid out for), else bark colours all round
_BARK_EDGES = CLASS_EDGES[1]


def set_dir(name: str) -> Path:
    """The folder of shipped tile set ``name`` (a real folder: the package is installed
    unzipped, as setuptools does for package data). ``name`` must be one of :data:`SETS`."""
    if name not in SETS:
        raise ValueError(f"unknown bark tile set {name!r}; shipped: {', '.join(SETS)}")
    return Path(__file__).parent / name


def installed_set_dir(name: str) -> Path:
    """:func:`set_dir`, checked to exist: an error naming the set, never its folder (a
    placeholder in its stead would hide a broken install)."""
    from forest.errors import ForestError

    folder = set_dir(name)
    if not folder.is_dir():
        raise ForestError(
            f"the shipped bark tile set {name!r} is missing from this installation", path="bark"
        )
    return folder


@functools.cache
def shipped_manifest(name: str) -> TileSetManifest:
    """The manifest of shipped set ``name`` (its classes: the default ones, and the lower
    trunk's where the species has one); the default manifest for a set missing from this
    installation (whose scene then renders with placeholder bark, or names its folder)."""
    from forest.bark.tiles import manifest_for

    folder = set_dir(name)
    return manifest_for(folder) if (folder / "manifest.json").is_file() else DEFAULT_MANIFEST


def default_dir() -> Path:
    """The folder of the shipped default tile set."""
    return set_dir(DEFAULT_SET)


def manifest_classes(manifest: TileSetManifest = DEFAULT_MANIFEST) -> tuple[ClassSpec, ...]:
    """The classes to build for ``manifest`` (names, ids, counts; its edges, else the
    paper's colouring), in slice order."""
    from forest.bark.tileset import ClassSpec

    ordered = sorted(manifest.classes, key=lambda c: c.first)
    return tuple(
        ClassSpec(c.name, c.id, c.count, c.edges or CLASS_EDGES.get(c.id, _BARK_EDGES))
        for c in ordered
    )


def example(
    name: str, seed: int, size: int = EXAMPLE_SIZE, width: int = EXAMPLE_WIDTH
) -> np.ndarray:
    """``(size, width, 3)`` uint8: example ``seed`` of set ``name``."""
    if name == DEFAULT_SET:
        return bark_example(size, width, seed)
    return species_example(name, size, width, seed)


def make_set(name: str, folder: Path) -> TileSet:
    """Build shipped set ``name`` into ``folder`` (examples made on the fly)."""
    from forest.bark.images import read_example, write_png
    from forest.bark.tileset import (
        TileGeometry,
        build_tileset,
        lower_classes,
        stack_lower,
        write_tileset,
    )

    prefix = "procedural-bark" if name == DEFAULT_SET else f"procedural-{name}"
    geom = TileGeometry.for_size(DEFAULT_TILE_SIZE)
    with tempfile.TemporaryDirectory() as tmp:

        def examples(make: Callable[[int], np.ndarray], stem: str) -> list[ExampleImage]:
            out = []
            for seed in EXAMPLE_SEEDS:
                path = Path(tmp) / f"{stem}-{seed}.png"
                write_png(path, make(seed))
                out.append(read_example(path, min_size=DEFAULT_TILE_SIZE))
            return out

        upper = examples(lambda seed: example(name, seed), prefix)
        if name not in LOWER_TRUNK:
            ts = build_tileset(upper, manifest_classes(), geom, DEFAULT_SEED, slide=SLIDE)
        else:
            lower = examples(
                lambda seed: lower_example(name, EXAMPLE_SIZE, EXAMPLE_WIDTH, seed),
                f"{prefix}-lower",
            )
            up = build_tileset(upper, manifest_classes(), geom, DEFAULT_SEED, slide=SLIDE)
            low = build_tileset(
                lower,
                lower_classes([c for c in manifest_classes() if c.name in LOWER_CLASSES]),
                geom,
                DEFAULT_SEED,
                slide=SLIDE,
            )
            ts = stack_lower(up, low, LOWER_TRUNK[name])
    write_tileset(ts, folder)
    colour = tiles_mean_colour(ts.tiles, ts.manifest)
    (folder / MEAN_COLOUR_FILE).write_text(json.dumps(colour) + "\n", encoding="utf-8")
    return ts


@functools.cache
def mean_colour(name: str) -> tuple[float, float, float]:
    """Linear RGB (0 to 1) mean of shipped set ``name``'s tiles: the flat bark colour for
    viewers that do not read the tiles (the lower trunk's left out: most of a tree is not).
    Read from the set's :data:`MEAN_COLOUR_FILE`, which :func:`make_set` writes beside the
    tiles (a test holds it equal to the tiles' mean): every scene write wants this colour, and
    reading and decoding the texture array for it took 30-50 ms of a one-tree run. A set
    without the file is measured from its texture array."""
    stored = set_dir(name) / MEAN_COLOUR_FILE
    if stored.is_file():
        r, g, b = (float(c) for c in json.loads(stored.read_text(encoding="utf-8")))
        return (r, g, b)
    return measured_mean_colour(name)


def measured_mean_colour(name: str) -> tuple[float, float, float]:
    """:func:`mean_colour` measured from the set's texture array (what its file stores)."""
    from forest.bark.images import read_texture_array

    tiles = read_texture_array(set_dir(name) / "bark_array.tif")
    return tiles_mean_colour(tiles, shipped_manifest(name))


def tiles_mean_colour(tiles: np.ndarray, manifest: TileSetManifest) -> tuple[float, float, float]:
    """The linear mean colour of the ``(n, h, w, c)`` sRGB bytes ``tiles`` of a set with
    ``manifest``, its lower trunk's slices left out."""
    tiles = tiles[..., :3]
    lower = [c.first for c in manifest.classes if c.stands_for is not None]
    tiles = tiles[: min(lower, default=len(tiles))]
    # sRGB decoded through a table of the 256 byte values: the same numbers as decoding each
    # texel, a tenth of the time (every small scene's write waits on this)
    v = np.arange(256) / 255.0
    decode = np.where(v <= 10 / 255.0, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    lin = decode[tiles]
    r, g, b = (float(c) for c in lin.reshape(-1, 3).mean(axis=0))
    return (r, g, b)
