"""Tile sets shipped with the package.

``default/``: 8 bark and 4 fork tiles of 128 px (the classes of
:data:`schemas.tileset.DEFAULT_MANIFEST`), quilted from two procedural bark examples of
384 px made by :func:`forest.bark.barkgen.bark_example` (seeds 1 and 2), tile-set seed 7. Rebuild it
with ``python -m forest.bark.tilesets`` after changing the quilting or the bark generator; a test
fails while the shipped files differ from what the code makes.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from forest.bark.barkgen import bark_example
from forest.bark.images import write_png
from forest.bark.tileset import TileSet, default_classes, make_tileset

DEFAULT_TILE_SIZE = 128
DEFAULT_COUNTS = (8, 4)  # bark, fork
DEFAULT_SEED = 7
EXAMPLE_SIZE = 384
EXAMPLE_SEEDS = (1, 2)


def default_dir() -> Path:
    """The folder of the shipped default tile set (a real folder: the package is installed
    unzipped, as setuptools does for package data)."""
    return Path(__file__).parent / "default"


def make_default(folder: Path) -> TileSet:
    """Build the default tile set into ``folder`` (examples made on the fly)."""
    with tempfile.TemporaryDirectory() as tmp:
        paths = []
        for seed in EXAMPLE_SEEDS:
            path = Path(tmp) / f"procedural-bark-{seed}.png"
            write_png(path, bark_example(EXAMPLE_SIZE, EXAMPLE_SIZE, seed))
            paths.append(path)
        classes = default_classes(*DEFAULT_COUNTS)
        return make_tileset(paths, folder, classes, size=DEFAULT_TILE_SIZE, seed=DEFAULT_SEED)
