"""The ``forest`` command line. Input errors print one line naming what is wrong and exit 2."""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import click

from forest.errors import ForestError

F = TypeVar("F", bound=Callable[..., Any])
EXIT_INPUT = 2
# forests at least this big get a progress bar on stderr
PROGRESS_TREES = 200


def input_errors(fn: F) -> F:
    """Turn a ForestError into ``error: <path>: <message>`` and exit code 2."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except ForestError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(EXIT_INPUT)

    return wrapper  # type: ignore[return-value]


@contextmanager
def stage_progress(enabled: bool, label: str) -> Iterator[Callable[[str, int, int], None]]:
    """A progress callback ``(stage, done, total)`` drawing one bar per stage on stderr."""
    if not enabled:
        yield lambda stage, done, total: None
        return
    bars: dict[str, Any] = {}

    def update(stage: str, done: int, total: int) -> None:
        bar = bars.get(stage)
        if bar is None:
            for old in bars.values():
                old.render_finish()
            bar = bars[stage] = click.progressbar(
                length=total, label=f"{label}: {stage:<14}", file=sys.stderr
            )
            bar.__enter__()
        bar.update(done - bar.pos)

    try:
        yield update
    finally:
        for bar in bars.values():
            bar.__exit__(None, None, None)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="interlocking-forest", prog_name="forest")
def main() -> None:
    """Procedural forests from interlocking quad-mesh pieces, written as USD scenes."""
    from forest.memory import keep_freed_memory

    keep_freed_memory()


@main.command()
@input_errors
def presets() -> None:
    """List the grammar presets shipped with the package."""
    from forest.grammar import compile_grammar
    from forest.presets import load_preset, preset_names

    for name in preset_names():
        g = load_preset(name)
        cg = compile_grammar(g)
        click.echo(f"{name:<12} ~{cg.expected_pieces:6.0f} pieces/tree  {g.description}")


def _load_grammar(preset: str | None, grammar: Path | None) -> Any:
    from forest.grammar import load_grammar
    from forest.presets import load_preset

    if (preset is None) == (grammar is None):
        raise ForestError("give exactly one of --preset NAME or --grammar FILE", path="grammar")
    return load_preset(preset) if preset is not None else load_grammar(grammar)  # type: ignore[arg-type]


@main.command()
@click.option("--preset", help="Name of a shipped grammar (see `forest presets`).")
@click.option("--grammar", type=click.Path(path_type=Path), help="A grammar JSON file.")
@click.option("--seed", type=click.IntRange(0, 2**63 - 1), default=0, show_default=True)
@click.option("--trees", type=int, default=1, show_default=True)
@click.option(
    "--area",
    type=(float, float),
    default=(20.0, 20.0),
    show_default=True,
    metavar="W D",
    help="Width and depth in metres of the area the trees stand in.",
)
@click.option(
    "--placement", type=click.Choice(["poisson", "grid"]), default="poisson", show_default=True
)
@click.option(
    "--frames",
    type=int,
    default=0,
    show_default=True,
    help="Wind frames to sample (0: a still, posed forest).",
)
@click.option("--fps", type=float, default=24.0, show_default=True)
@click.option(
    "--wind",
    "wind_deg",
    type=float,
    default=4.0,
    show_default=True,
    help="Wind sway at the tips, degrees.",
)
@click.option(
    "--segments",
    type=int,
    default=1,
    show_default=True,
    help="Piece resolution: quad rings per tube section.",
)
@click.option("--skinned", is_flag=True, help="Also bake each tree as SkelRoot + skinned Mesh.")
@click.option(
    "--tiles",
    "tiles_dir",
    metavar="DIR",
    help="Tile-set folder, relative to the scene: the material reads its bark.<UDIM>.png "
    "and tile indices follow its manifest.json.",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path),
    required=True,
    help="OUT.usda, OUT.usdc or OUT.usdz",
)
@input_errors
def generate(
    preset: str | None,
    grammar: Path | None,
    seed: int,
    trees: int,
    area: tuple[float, float],
    placement: str,
    frames: int,
    fps: float,
    wind_deg: float,
    segments: int,
    skinned: bool,
    tiles_dir: str | None,
    output: Path,
) -> None:
    """Generate a forest from a grammar and a seed and write it as USD."""
    from forest.generate import ForestOptions, generate_forest
    from forest.skeleton import Wind
    from forest.tiles import manifest_for
    from forest.usd_files import check_output_path
    from forest.usd_scene import write_scene
    from schemas.tileset import DEFAULT_MANIFEST

    check_output_path(output)
    g = _load_grammar(preset, grammar)
    manifest = manifest_for(output.parent / tiles_dir) if tiles_dir else DEFAULT_MANIFEST
    options = ForestOptions(
        trees=trees,
        area=area,
        frames=frames,
        fps=fps,
        placement=placement,  # type: ignore[arg-type]
        segments=segments,
        wind=Wind(strength_deg=wind_deg),
    )
    with stage_progress(trees >= PROGRESS_TREES or (skinned and trees > 20), "forest") as bar:
        forest = generate_forest(g, seed, options, manifest=manifest, progress=bar)
        write_scene(forest, output, skinned=skinned, tiles=tiles_dir, progress=bar)
    click.echo(
        f"wrote {output}: {trees} tree(s), {forest.n_instances} pieces, "
        f"{len(forest.bones)} bones, {frames} frame(s)" + (", skinned" if skinned else "")
    )


@main.command()
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path),
    default=Path("demo"),
    show_default=True,
    help="Folder to write into.",
)
@input_errors
def demo(output: Path) -> None:
    """Write a small forest (and one skinned, animated tree) into a folder."""
    from forest.generate import ForestOptions, generate_forest
    from forest.presets import load_preset
    from forest.usd_scene import write_scene

    try:
        output.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ForestError(f"cannot create folder: {exc.strerror}", path=str(output)) from None
    jobs = [
        ("forest.usdc", "almond", ForestOptions(trees=25, area=(30.0, 30.0), frames=48), False),
        ("conifers.usda", "conifer", ForestOptions(trees=6, area=(12.0, 12.0)), False),
        ("almond_skinned.usdz", "almond", ForestOptions(trees=1, frames=48), True),
    ]
    for name, preset, options, skinned in jobs:
        forest = generate_forest(load_preset(preset), 1, options)
        path = write_scene(forest, output / name, skinned=skinned)
        kind = "skinned + instanced" if skinned else "instanced"
        click.echo(
            f"{path}  {path.stat().st_size / 1e6:7.2f} MB  {preset}: {options.trees} "
            f"tree(s), {forest.n_instances} pieces, {options.frames} wind frame(s), {kind}"
        )
    click.echo("open them in usdview, Blender (File > Import > USD) or any USD tool")


@main.group()
def bench() -> None:
    """Benchmarks: figures and ratios against a baseline run side by side."""


@bench.command("generate")
@click.option("--trees", type=int, default=10_000, show_default=True)
@click.option("--preset", default="alternating", show_default=True)
@click.option("--repeat", type=int, default=3, show_default=True)
@input_errors
def bench_generate(trees: int, preset: str, repeat: int) -> None:
    """Pieces/s of expansion + assembly + pose + tiles against a per-piece Python loop, and
    seconds to write the forest as .usdc."""
    from forest.bench import run_generate_bench

    run_generate_bench(trees=trees, preset=preset, repeat=repeat, echo=click.echo)


@main.command()
@click.argument("scene", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True, help="Preview PNG.")
@click.option(
    "--metrics", type=click.Path(path_type=Path), help="Frame-time metrics JSON to write."
)
@click.option("--width", type=int, default=640, show_default=True)
@click.option("--height", type=int, default=480, show_default=True)
@click.option(
    "--tess-max",
    type=float,
    default=8.0,
    show_default=True,
    help="Highest tessellation level (nearest edges); it halves every --lod-half metres.",
)
@click.option(
    "--lod-half",
    type=float,
    help="Metres over which the level halves (0: every edge at --tess-max). "
    "Default: a quarter of the forest's diagonal.",
)
@click.option("--alpha", type=float, default=0.75, show_default=True, help="Phong shape factor.")
@click.option(
    "--frame", type=int, default=0, show_default=True, help="First palette (wind) sample."
)
@click.option(
    "--frames", type=int, default=1, show_default=True, help="Frames to draw and measure."
)
@click.option(
    "--tiles",
    "tiles_dir",
    type=click.Path(path_type=Path),
    help="Tile-set folder (default: the one the scene's material names, else a placeholder).",
)
@click.option(
    "--per-instance", is_flag=True, help="One draw call per piece instance (for comparison)."
)
@click.option("--no-cull", is_flag=True, help="Keep patches outside the view (for comparison).")
@click.option("--no-foliage", is_flag=True, help="Leave the leaf clouds out.")
@click.option(
    "--foliage-geometry",
    is_flag=True,
    help="Draw the real leaf-cloud mesh at every cloud instead of 2.5D impostors (comparison).",
)
@input_errors
def render(
    scene: Path,
    output: Path,
    metrics: Path | None,
    width: int,
    height: int,
    tess_max: float,
    lod_half: float | None,
    alpha: float,
    frame: int,
    frames: int,
    tiles_dir: Path | None,
    per_instance: bool,
    no_cull: bool,
    no_foliage: bool = False,
    foliage_geometry: bool = False,
) -> None:
    """Render a forest scene offscreen (EGL) to a preview PNG, with frame-time metrics."""
    from worker.render_job import RenderRequest, render_file

    m = render_file(
        RenderRequest(
            scene=scene,
            output=output,
            metrics=metrics,
            width=width,
            height=height,
            tess_max=tess_max,
            alpha=alpha,
            lod_half=lod_half,
            frame=frame,
            frames=frames,
            tiles=tiles_dir,
            per_instance=per_instance,
            cull=not no_cull,
            foliage=None if no_foliage else "geometry" if foliage_geometry else "impostor",
        )
    )
    med = m.median
    gpu = f", GPU {med.gpu_ms:.2f} ms" if med.gpu_ms is not None else ""
    click.echo(
        f"wrote {output}: {m.width}x{m.height}, {m.instances} pieces in "
        f"{m.frames[0].draw_calls} draw call(s), {med.primitives:.0f} triangles; median of "
        f"{len(m.frames)} frame(s): CPU {med.cpu_ms:.2f} ms{gpu}"
    )
    if m.foliage is not None and m.frames[0].foliage is not None:
        fo, f0 = m.foliage, m.frames[0].foliage
        click.echo(
            f"foliage: {fo.clouds} leaf clouds as {fo.mode}"
            + (
                f" ({fo.impostor_size} px, pass 1 ran {fo.impostor_renders} time(s))"
                if fo.mode == "impostor"
                else ""
            )
            + f"; pass 2: {f0.billboards.draw_calls} draw call(s), {f0.billboards.primitives} "
            "triangles"
        )
    click.echo(f"renderer: {m.renderer}")
    if metrics is not None:
        click.echo(f"wrote {metrics}")


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
@input_errors
def tiles(examples: tuple[Path, ...], output: Path, per_class: int, size: int, seed: int) -> None:
    """Build a bark tile set from example images by image quilting (paper 5.2).

    Writes bark.<UDIM>.png per texture-array slice, bark_array.tif (all slices as subimages),
    edge.<colour>.png and corner.png (the patterns every tile's border shows) and
    manifest.json (classes, sources with checksums, seed, sizes, file names).
    """
    from forest.tileset import make_tileset

    ts = make_tileset(examples, output, per_class, size, seed)
    m = ts.manifest
    assert m.files is not None
    counts = ", ".join(f"{c.count} {c.name}" for c in m.classes)
    click.echo(
        f"wrote {output}: {len(ts.tiles)} tiles of {size} px ({counts}) quilted from "
        f"{len(examples)} example(s), seed {seed}"
    )
    names = [m.files.slices[0], "..", m.files.slices[-1]] if len(ts.tiles) > 2 else m.files.slices
    extra = [m.files.array or "", *(p.file for p in m.edge_patterns), "manifest.json"]
    click.echo("  " + " ".join(names) + ", " + ", ".join(x for x in extra if x))
    if ts.reused:
        region = size - 2 * (m.border or 0)
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
    from forest.bench_tiles import run_tiles_bench

    run_tiles_bench(size=size, tiles=n_tiles, repeat=repeat, echo=click.echo)



@main.command()
@click.argument("scene", type=click.Path(path_type=Path))
@click.option(
    "-o", "--output", type=click.Path(path_type=Path), required=True, help="Contact sheet PNG."
)
@click.option("--frame", type=int, default=0, show_default=True, help="Palette (wind) sample.")
@click.option("--width", type=click.IntRange(200, 8192), default=1400, show_default=True)
@click.option("--height", type=click.IntRange(150, 8192), default=1050, show_default=True)
@input_errors
def inspect(scene: Path, output: Path, frame: int, width: int, height: int) -> None:
    """Diagnostic contact sheet (pyvista, offscreen): skeleton, rims and tile classes, tile
    indices, piece types."""
    from forest.errors import OutputError
    from forest.usd_read import read_scene
    from worker.inspect_sheet import contact_sheet

    if output.suffix.lower() != ".png":
        raise OutputError("the contact sheet is a PNG: name it *.png", path=str(output))
    if not output.parent.resolve().is_dir():
        raise OutputError("folder does not exist", path=str(output))
    s = read_scene(scene)
    if not 0 <= frame < len(s.palettes):
        raise ForestError(
            f"the scene has {len(s.palettes)} palette sample(s), got {frame}", path="frame"
        )
    contact_sheet(s, output, frame, (width, height))
    click.echo(f"wrote {output}: {s.n_instances} pieces, frame {frame}")



@bench.command("render")
@click.option(
    "--trees",
    "trees_text",
    default="1,10,50",
    show_default=True,
    help="Comma-separated tree counts, e.g. 1,10,50,100,250,500,1000 (the paper's).",
)
@click.option(
    "--levels",
    "levels_text",
    default="1,10",
    show_default=True,
    help="Comma-separated tessellation levels, the same on every edge.",
)
@click.option("--preset", default="alternating", show_default=True)
@click.option("--width", type=click.IntRange(16, 8192), default=320, show_default=True)
@click.option("--height", type=click.IntRange(16, 8192), default=240, show_default=True)
@click.option("--frames", type=click.IntRange(1, 1000), default=3, show_default=True)
@click.option("--no-naive", is_flag=True, help="Skip the one-draw-call-per-piece baseline.")
@click.option(
    "--foliage-trees",
    "foliage_text",
    default="100,1000",
    show_default=True,
    help="Tree counts for impostor foliage against the real leaf-cloud mesh ('none': skip).",
)
@click.option(
    "--plot",
    type=click.Path(path_type=Path),
    default=Path("bench-render.png"),
    show_default=True,
    help="PNG plot of frame time against tree count.",
)
@input_errors
def bench_render(
    trees_text: str,
    levels_text: str,
    preset: str,
    width: int,
    height: int,
    frames: int,
    no_naive: bool,
    plot: Path,
    foliage_text: str = "none",
) -> None:
    """Frame time against tree count, instanced against one draw call per piece, at fixed
    tessellation levels (the paper's Figure 16 and its levels 1 and 10)."""
    from worker.bench import parse_counts, run_render_bench

    try:
        levels = [float(x) for x in levels_text.split(",") if x.strip()]
    except ValueError:
        raise ForestError(f"expected numbers, got {levels_text!r}", path="levels") from None
    if not levels or not all(1.0 <= lv <= 64.0 for lv in levels):
        raise ForestError("levels must be in [1, 64]", path="levels")
    run_render_bench(
        parse_counts(trees_text),
        levels,
        preset=preset,
        size=(width, height),
        frames=frames,
        naive=not no_naive,
        plot=plot,
        echo=click.echo,
        foliage_trees=(
            [] if foliage_text.strip() == "none" else parse_counts(foliage_text, "foliage_trees")
        ),
    )


@main.command()
@click.option(
    "--data",
    "data_dir",
    type=click.Path(path_type=Path),
    default=Path("forest-data"),
    show_default=True,
    envvar="FOREST_DATA_DIR",
    help="Folder of the embedded job store, broker and artifacts.",
)
@click.option("--host", default="127.0.0.1", show_default=True)
@click.option("--port", type=click.IntRange(0, 65535), default=8000, show_default=True)
@click.option("--workers", type=click.IntRange(0, 64), default=2, show_default=True)
def serve(data_dir: Path, host: str, port: int, workers: int) -> None:
    """The HTTP API plus local worker processes. With no FOREST_DATABASE_URL /
    FOREST_BROKER_URL / FOREST_ARTIFACTS_DIR set, everything lives in --data (SQLite)."""
    import os

    from service.embedded import serve as run_serve
    from service.settings import get_settings, override_settings

    os.environ["FOREST_DATA_DIR"] = str(data_dir.resolve())
    override_settings(None)
    s = get_settings()
    click.echo(f"forest serve: http://{host}:{port} (docs at /docs), {workers} worker(s)")
    click.echo(f"  jobs {s.db_url.split('@')[-1]}, broker {s.broker.split('@')[-1]}")
    run_serve(s, host, port, workers)


@main.command("worker")
@click.option(
    "-Q", "--queues", default="default,gpu", show_default=True, help="Queues to consume."
)
@click.option("--name", help="Celery node name (default forest-<pid>@<host>).")
@click.option("--loglevel", default="info", show_default=True)
@click.option("--list", "list_kinds", is_flag=True, help="List the job kinds this worker runs.")
def worker_cmd(queues: str, name: str | None, loglevel: str, list_kinds: bool) -> None:
    """Join a cluster: consume jobs from the broker and job store in the settings
    (FOREST_BROKER_URL, FOREST_DATABASE_URL, FOREST_ARTIFACTS_DIR)."""
    if list_kinds:
        from service.dispatch import KIND_QUEUES
        from worker.tasks import KINDS

        for kind in KINDS:
            click.echo(f"{kind}\tqueue {KIND_QUEUES[kind]}")
        return
    from worker.main import run_worker

    try:
        run_worker([q.strip() for q in queues.split(",") if q.strip()], name, loglevel)
    except ValueError as exc:
        click.echo(f"error: queues: {exc}", err=True)
        sys.exit(EXIT_INPUT)



@bench.command("service")
@click.option("--preset", default="almond", show_default=True)
@click.option("--concurrency", default="1,8,32", show_default=True, help="Client counts.")
@click.option("--requests", type=click.IntRange(1, 100_000), default=200, show_default=True)
@click.option("--workers", default="1,2", show_default=True, help="Worker counts for jobs.")
@click.option("--jobs", type=click.IntRange(1, 10_000), default=16, show_default=True)
@click.option("--trees", type=click.IntRange(1, 10_000), default=200, show_default=True)
@input_errors
def bench_service(
    preset: str, concurrency: str, requests: int, workers: str, jobs: int, trees: int
) -> None:
    """Latency (p50, p99) and req/s of POST /v1/trees at several client counts, and
    forest-job throughput (trees/s) with 1 and 2 workers, on the embedded server."""
    from service.bench import run_service_bench

    def counts(text: str, name: str) -> list[int]:
        try:
            values = [int(x) for x in text.split(",") if x.strip()]
        except ValueError:
            raise ForestError(f"expected integers, got {text!r}", path=name) from None
        if not values or min(values) < 1:
            raise ForestError("expected positive integers", path=name)
        return values

    run_service_bench(
        preset, counts(concurrency, "concurrency"), requests, counts(workers, "workers"), jobs,
        trees, echo=click.echo,
    )


if __name__ == "__main__":
    main()
