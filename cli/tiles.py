"""Commands that make bark tile sets: ``tiles``, ``bench tiles``."""

from __future__ import annotations

from pathlib import Path

import click

from cli.app import bench, input_errors, main, needs
from cli.progress import quiet_option, show_progress


@main.command()
@click.argument(
    "examples", nargs=-1, required=True, type=click.Path(path_type=Path), metavar="EXAMPLE_IMAGE..."
)
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path),
    required=True,
    help="Folder to write the tile set into (created if missing).",
)
@click.option(
    "--per-class",
    type=click.IntRange(1, 499),
    default=8,
    show_default=True,
    help="Tiles in each class (bark and fork).",
)
@click.option(
    "--size", type=click.IntRange(16, 4096), default=256, show_default=True, help="Tile side, px."
)
@click.option("--seed", type=click.IntRange(0, 2**63 - 1), default=0, show_default=True)
@quiet_option
@input_errors
def tiles(
    examples: tuple[Path, ...],
    output: Path,
    per_class: int,
    size: int,
    seed: int,
    quiet: bool = False,
) -> None:
    """Build a bark tile set from example images by image quilting (paper 5.2).

    Writes bark.<UDIM>.png per texture-array slice, bark_array.tif (all slices as subimages),
    edge.<colour>.png and corner.png (the patterns every tile's border shows) and
    manifest.json (classes, sources with checksums, seed, sizes, file names).
    """
    from forest.bark.tileset import TileGeometry, default_classes, make_tileset
    from schemas.tileset import MANIFEST_FILE

    classes = default_classes(per_class, per_class)
    with show_progress("tiles", quiet) as bar:
        ts = make_tileset(examples, output, classes, size, seed, progress=bar)
    m = ts.manifest
    assert m.files is not None
    counts = ", ".join(f"{c.count} {c.name}" for c in m.classes)
    click.echo(
        f"wrote {output}: {len(ts.tiles)} tiles of {size} px ({counts}) quilted from "
        f"{len(examples)} example(s), seed {seed}"
    )
    names = [m.files.slices[0], "..", m.files.slices[-1]] if len(ts.tiles) > 2 else m.files.slices
    extra = [m.files.array or "", *(p.file for p in m.edge_patterns), MANIFEST_FILE]
    click.echo("  " + " ".join(names) + ", " + ", ".join(x for x in extra if x))
    if ts.reused:
        region = TileGeometry.for_size(size).region
        click.echo(
            f"note: the examples hold only {len(ts.tiles) - ts.reused} disjoint {region} px "
            f"interiors; {ts.reused} tile(s) partly repeat others: give more or larger "
            "examples, or fewer or smaller tiles",
            err=True,
        )


@bench.command("tiles")
@click.option("--size", type=click.IntRange(16, 1024), default=256, show_default=True)
@click.option("--tiles", "n_tiles", type=click.IntRange(2, 256), default=16, show_default=True)
@click.option("--repeat", type=click.IntRange(1, 100), default=3, show_default=True)
@input_errors
def bench_tiles(size: int, n_tiles: int, repeat: int) -> None:
    """Milliseconds per tile of the quilting stitch against a plain-Python baseline, and of
    the whole tile-set build."""
    # its examples are procedural bark (forest.bark.barkgen), filtered with scipy.ndimage
    needs("dev", "scipy")
    from bench.tiles import run_tiles_bench

    run_tiles_bench(size=size, tiles=n_tiles, repeat=repeat, echo=click.echo)
