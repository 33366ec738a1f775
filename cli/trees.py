"""Commands that make forests: ``presets``, ``generate``, ``demo``, ``bench generate``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import click

from cli.app import bench, input_errors, main
from cli.progress import Quiet, quiet_option, show_progress
from forest.errors import ForestError


class FiniteRange(click.FloatRange):
    """A float range that refuses NaN and infinities too (``FloatRange`` lets NaN through: no
    comparison with NaN is true); the bounds are the service's request limits."""

    name = "finite float range"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        out = super().convert(value, param, ctx)
        if not math.isfinite(out):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return out


@main.command()
@input_errors
def presets() -> None:
    """List the grammar presets shipped with the package."""
    from forest.growth.compile import compile_grammar
    from forest.growth.presets import load_preset, preset_names

    for name in preset_names():
        g = load_preset(name)
        cg = compile_grammar(g)
        click.echo(f"{name:<12} ~{cg.expected_pieces:6.0f} pieces/tree  {g.description}")


def _load_grammar(preset: str | None, grammar: Path | None, bark: str | None = None) -> Any:
    from forest.growth.presets import PresetOrGrammarError, grammar_of

    try:
        return grammar_of(preset, grammar, bark)
    except PresetOrGrammarError:  # said with the command's flags
        raise ForestError(
            "give exactly one of --preset NAME or --grammar FILE", path="grammar"
        ) from None


@main.command()
@input_errors
def recipes() -> None:
    """List the built-in forest recipes (mixed stands for `forest generate --recipe`)."""
    from forest.stand.recipes import builtin_summaries

    for r in builtin_summaries():
        click.echo(f"{r.name:<16} {r.description}")
        click.echo(f"{'':<16} layers: {'; '.join(r.layers)}")


@main.command()
@click.option("--preset", help="Name of a shipped grammar (see `forest presets`).")
@click.option("--grammar", type=click.Path(path_type=Path), help="A grammar JSON file.")
@click.option(
    "--recipe",
    help="A mixed forest: a built-in recipe's name (see `forest recipes`) or a recipe JSON "
    "file. Writes OUT (a .usda/.usdc root layer with the terrain) and OUT_layers/<layer>.usdc, "
    "one scene per species layer; --trees splits by the layers' shares.",
)
@click.option("--seed", type=click.IntRange(0, 2**63 - 1), default=0, show_default=True)
@click.option("--trees", type=int, default=1, show_default=True)
@click.option(
    "--area",
    type=(FiniteRange(0, 1e6, min_open=True), FiniteRange(0, 1e6, min_open=True)),
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
@click.option("--fps", type=FiniteRange(0, 1000, min_open=True), default=24.0, show_default=True)
@click.option(
    "--wind",
    "wind_deg",
    type=FiniteRange(0, 90),
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
@click.option(
    "--skinned/--no-skinned",
    default=None,
    help="Bake each tree as SkelRoot + skinned Mesh, the composed default (exact skinning "
    "in any USD tool), or write only the posed instanced pieces. Default: skinned for up "
    "to 64 trees and 20,000 pieces (forest.usd.scene.SKINNED_MAX_TREES and "
    "SKINNED_MAX_PIECES), posed above; a .usdz is always skinned.",
)
@click.option(
    "--lod/--no-lod",
    default=None,
    help="Write each skinned tree's levels of detail as a variant set 'lod' (USD; default "
    "on): lod0 the full tree (selected), lod1 without the thinnest pieces (about 1/4 of the "
    "triangles, at most 40 k), lod2 the limbs and crown cards (1/20, at most 8 k; also the "
    "leaves' proxy), lod3 a baked impostor card pair with its view atlas beside the other "
    "pictures (needs the render extra's GL; skipped with a note without it). A .glb's levels "
    "follow --profile instead (--lod is refused there).",
)
@click.option(
    "--season",
    type=click.Choice(["summer", "autumn"]),
    default="summer",
    show_default=True,
    help="Leaf colours: the species' summer palette or its autumn one.",
)
@click.option(
    "--bark",
    # forest.bark.tilesets.SETS spelled out: loading this module loads no numpy (a test checks)
    type=click.Choice(
        ["default", "oak", "almond", "birch", "pine", "spruce", "willow", "poplar", "hazel"]
    ),
    help="A shipped bark tile set in place of the grammar's own (its 'bark').",
)
@click.option(
    "--tiles",
    "tiles_dir",
    metavar="DIR",
    help="Tile-set folder, relative to the scene: the material reads its bark.<UDIM>.png "
    "instead of the species' shipped set (a .usdz or .glb bakes them into its atlas), and "
    "tile indices follow its manifest.json.",
)
@click.option(
    "--textures/--no-textures",
    default=True,
    show_default=True,
    help="USD: bark tiles and the leaf picture (cards cut to leaves) written beside a "
    ".usda/.usdc in OUT.textures/ (relative paths) or inside a .usdz (one bark atlas); "
    "--no-textures keeps flat colours and writes no picture. A .glb always packs its own.",
)
@click.option(
    "--tile-size",
    type=FiniteRange(0, 1e6, min_open=True),
    default=None,
    metavar="M",
    help="Cut the area into M x M metre tiles: writes OUT (.usda/.usdc root layer, each tile "
    "a payload with its extent) and OUT_tiles/<i>_<j>.usdc, one per tile (flat colours); "
    "placement is seamless across tiles and allows more trees than one scene.",
)
@click.option(
    "--glb-pack",
    type=click.Choice(["quantized", "meshopt", "float"]),
    default="quantized",
    show_default=True,
    help="How a .glb stores its data: quantized (KHR_mesh_quantization, read by every glTF "
    "importer, Blender 4.2 included), meshopt (quantized and compressed with "
    "EXT_meshopt_compression, about half the bytes, needs a meshopt decoder: three.js, "
    "Babylon.js, glTFast; Blender 4.2 refuses it) or float (uncompressed float32).",
)
@click.option(
    "--profile",
    type=click.Choice(["game", "film"]),
    default=None,
    help="What a .glb is for: game (the default: per tree LOD0-LOD2 skinned meshes and an "
    "impostor card pair as LOD3, chained with MSFT_lod, at most 256 joints, LOD0 at most "
    "100 k triangles (--lod0-triangles), welded bark on a repeating bark picture, one "
    "material per kind) or film (the full tree on every joint with the tile set's atlas, no "
    "levels). .glb only.",
)
@click.option(
    "--lod0-triangles",
    type=int,
    default=None,
    metavar="N",
    help="The game profile's LOD0 budget (default 100,000; at least 40,000): a tree over it "
    "drops its thinnest twigs and thins its leaf cards down to it. A mature oak with 24 wind "
    "frames is about 5.5 MB at the default, 7 MB at 150,000. .glb game profile only.",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path),
    required=True,
    help="OUT.usda, OUT.usdc (with its pictures in OUT.textures/), OUT.usdz (skinned trees "
    "and pictures inside, for Quick Look / AR), or OUT.glb (glTF 2.0 binary: skinned trees, "
    "wind animation, textures inside, for game engines and web viewers)",
)
@quiet_option
@input_errors
def generate(
    preset: str | None,
    grammar: Path | None,
    recipe: str | None,
    seed: int,
    trees: int,
    area: tuple[float, float],
    placement: str,
    frames: int,
    fps: float,
    wind_deg: float,
    segments: int,
    skinned: bool | None,
    lod: bool | None,
    season: str,
    bark: str | None,
    tiles_dir: str | None,
    textures: bool,
    tile_size: float | None,
    glb_pack: str,
    profile: str | None,
    lod0_triangles: int | None,
    output: Path,
    quiet: bool = False,
) -> None:
    """Generate a forest from a grammar and a seed and write it as USD or glTF (by the
    output's suffix)."""
    from forest.bark.tiles import manifest_for
    from forest.export import SCENE_SUFFIXES, is_glb, write_forest
    from forest.growth.generate import ForestOptions, generate_forest
    from forest.growth.wind import Wind
    from forest.usd.files import check_output_path
    from forest.usd.scene import wants_skinned

    check_output_path(output, SCENE_SUFFIXES)
    glb = is_glb(output)
    if recipe is not None:
        if preset is not None or grammar is not None:
            raise ForestError("give --recipe or --preset/--grammar, not both", path="recipe")
        if output.suffix.lower() == ".usdz" or tiles_dir:
            raise ForestError(
                "--recipe writes a USD root layer (.usda or .usdc) or one .glb, and takes no "
                "--tiles",
                path="recipe",
            )
        if bark is not None:
            raise ForestError("--bark: a recipe's layers keep their species' bark", path="bark")
        if not glb and (lod0_triangles or profile):
            raise ForestError("--profile and --lod0-triangles apply to a .glb only", path="profile")
        if glb and tile_size is not None:
            raise ForestError("--tile-size writes a USD root layer, not a .glb", path="tile_size")
        options = ForestOptions(
            trees=1,
            area=area,
            frames=frames,
            fps=fps,
            segments=segments,
            wind=Wind(strength_deg=wind_deg),
            season=season,  # type: ignore[arg-type]
        )
        _generate_stand(
            recipe,
            seed,
            trees,
            options,
            tile_size,
            skinned,
            textures,
            output,
            quiet,
            glb_pack=glb_pack,
            profile=profile,
            lod0_triangles=lod0_triangles,
        )
        return
    g = _load_grammar(preset, grammar, bark)
    # no tile folder: generate_forest takes the manifest of the shipped set the grammar names
    manifest = manifest_for(output.parent / tiles_dir) if tiles_dir else None
    options = ForestOptions(
        trees=trees,
        area=area,
        frames=frames,
        fps=fps,
        placement=placement,  # type: ignore[arg-type]
        segments=segments,
        wind=Wind(strength_deg=wind_deg),
        season=season,  # type: ignore[arg-type]
    )
    if tile_size is not None:
        if glb or tiles_dir:
            raise ForestError(
                "--tile-size writes a USD root layer (.usda or .usdc) and no --tiles",
                path="tile_size",
            )
        _generate_tiled(g, seed, options, tile_size, bool(skinned), output, quiet)
        return
    if lod and glb:
        raise ForestError(
            "a .glb's levels of detail are written by its --profile (game: LOD0-LOD3, "
            "film: none), not --lod",
            path="lod",
        )
    if profile is not None and not glb:
        raise ForestError("--profile applies to a .glb only", path="profile")
    if lod0_triangles is not None:
        from forest.gltf.document import game_lod0

        if not glb:
            raise ForestError("--lod0-triangles applies to a .glb only", path="lod0_triangles")
        game_lod0(lod0_triangles, "film" if profile == "film" else "game")  # before growing
    if skinned is False and output.suffix.lower() == ".usdz":
        raise ForestError(
            "a .usdz is always skinned (ARKit allows no PointInstancer): drop --no-skinned "
            "or write .usdc",
            path="skinned",
        )
    compiled = None
    if glb:  # the writer's vertex cap, estimated before any expansion
        from forest.caps import check_glb_vertices
        from forest.growth.compile import compile_grammar

        compiled = compile_grammar(g)
        check_glb_vertices(compiled, trees, segments, profile or "game", lod0_triangles)
    with show_progress("forest", quiet) as bar:
        grow = bar.steps(f"generate {trees} tree(s)")
        forest = generate_forest(
            g, seed, options, manifest=manifest, progress=grow, compiled=compiled
        )
        write_forest(
            forest,
            output,
            skinned=skinned,
            tiles=tiles_dir,
            textures=textures,
            progress=bar,
            packing=glb_pack,  # type: ignore[arg-type]
            lod=lod,
            profile=profile,  # type: ignore[arg-type]
            lod0_triangles=lod0_triangles,
        )
    wrote_skinned = glb or wants_skinned(forest, output, skinned)
    if glb and profile != "film" and not quiet:
        from forest.lod.impostor import gl_missing

        if (why := gl_missing()) is not None:
            click.echo(f"note: LOD3 (the impostor) not baked: {why}")
    elif lod is not False and not glb and not quiet:
        from forest.usd.scene import impostor_skipped

        if not wrote_skinned:
            if lod:
                click.echo("note: --lod applies to skinned trees; this scene is posed (--skinned)")
        elif textures and (why := impostor_skipped(forest)) is not None:  # asked for none
            click.echo(f"note: lod3 (the impostor) not baked: {why}")
    click.echo(
        f"wrote {output}: {trees} tree(s), {forest.n_instances} pieces, "
        f"{len(forest.bones)} bones, {frames} frame(s)"
        + (", skinned" if wrote_skinned else ", posed")
    )


def _generate_stand(
    recipe: str,
    seed: int,
    trees: int,
    options: Any,
    tile_size: float | None,
    skinned: bool | None,
    textures: bool,
    output: Path,
    quiet: bool,
    *,
    glb_pack: str,
    profile: str | None,
    lod0_triangles: int | None,
) -> None:
    """``forest generate --recipe``: place the stand, then grow and write each layer (a USD
    root layer and a scene per layer, or one .glb)."""
    from forest.export import is_glb
    from forest.stand.generate import plan_stand
    from forest.stand.recipes import load_recipe
    from forest.usd.stand import layers_folder, write_stand

    if lod0_triangles is not None:
        from forest.gltf.document import game_lod0

        game_lod0(lod0_triangles, "film" if profile == "film" else "game")  # before growing
    with show_progress("forest", quiet) as bar:
        stand = plan_stand(load_recipe(recipe), trees, options.area, seed)
        _check_stand_caps(stand, options, is_glb(output), tile_size, profile, lod0_triangles)
        if is_glb(output):
            from forest.gltf.stand import write_stand_glb

            write_stand_glb(
                stand,
                output,
                options,
                progress=bar.steps(f"grow and write {stand.trees} tree(s)"),
                packing=glb_pack,  # type: ignore[arg-type]
                profile=profile or "game",  # type: ignore[arg-type]
                lod0_triangles=lod0_triangles,
            )
        else:
            write_stand(
                stand,
                output,
                options,
                skinned=skinned,
                textures=textures,
                tile_size=tile_size,
                progress=bar.steps(f"grow and write {stand.trees} tree(s)"),
            )
    counts = ", ".join(
        f"{len(t)} {layer.name}"
        for layer, t in zip(stand.recipe.layers, stand.placement.layers, strict=True)
    )
    where = output if is_glb(output) else f"{output} and {layers_folder(output)}/"
    click.echo(f"wrote {where}: {stand.trees} tree(s) ({counts})")


def _check_stand_caps(
    stand: Any,
    options: Any,
    glb: bool,
    tile_size: float | None,
    profile: str | None,
    lod0_triangles: int | None,
) -> None:
    """Every layer's caps (pieces, palette; a .glb's vertices over all layers) from its
    placed trees (tiled: its fullest tile's, each layer tile being a forest of its own) and
    its estimate at their sizes, before the first layer grows."""
    from forest.caps import check_layers
    from forest.settings import get_settings
    from forest.usd.stand import largest_tile_counts

    settings = get_settings()
    counts = (
        [len(t) for t in stand.placement.layers]
        if tile_size is None
        else largest_tile_counts(stand, tile_size)
    )
    check_layers(
        stand.estimates(settings),
        counts,
        [layer.name for layer in stand.recipe.layers],
        options.frames,
        settings,
        glb=glb,
        segments=options.segments,
        profile=profile or "game",  # as write_stand_glb writes it
        lod0_triangles=lod0_triangles,
    )


def _generate_tiled(
    g: Any, seed: int, options: Any, tile_size: float, skinned: bool, output: Path, quiet: bool
) -> None:
    """``forest generate --tile-size``: every tile in turn (each its own forest), then the
    root layer."""
    from forest.growth.tiling import TilePlan, generate_tile
    from forest.usd.files import check_output_path
    from forest.usd.tiled import tiles_folder, write_root, write_tile

    out = check_output_path(output, (".usda", ".usdc"))
    plan = TilePlan(options.trees, options.area, tile_size, seed)
    threshold = plan.threshold()
    entries = []
    pieces = 0
    n = plan.nx * plan.nz
    with show_progress("forest", quiet) as bar:
        bar("tiles", 0, n)
        for k, (i, j) in enumerate(plan.tiles()):
            forest = generate_tile(g, plan, i, j, options, threshold=threshold)
            pieces += 0 if forest is None else forest.n_instances
            entries.append(write_tile(forest, out, i, j, skinned=skinned))
            del forest  # before the next tile is grown: one tile's arrays at a time
            bar("tiles", k + 1, n)
    write_root(out, entries, frames=options.frames, fps=options.fps, meta=plan.meta())
    click.echo(
        f"wrote {out} and {n} tile(s) in {tiles_folder(out)}: {options.trees} tree(s), "
        f"{pieces} pieces, {options.frames} frame(s)" + (", skinned" if skinned else "")
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
@quiet_option
@input_errors
def demo(output: Path, quiet: bool = False) -> None:
    """Write a small forest (and one skinned, animated tree) into a folder, and render a
    preview of the forest where an EGL driver is present."""
    from forest.growth.generate import ForestOptions, generate_forest
    from forest.growth.presets import load_preset
    from forest.usd.scene import write_scene

    try:
        output.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ForestError(f"cannot create folder: {exc.strerror}", path=str(output)) from None
    jobs = [
        # a swaying stand, posed pieces (light); a still mixed pair and one animated tree
        # skinned (exact in any DCC); .usda text of a skinned mature tree would be hundreds
        # of MB, so the demo writes binary layers
        ("forest.usdc", "almond", ForestOptions(trees=12, area=(24.0, 24.0), frames=24), False),
        ("birches.usdc", "birch", ForestOptions(trees=2, area=(8.0, 8.0)), True),
        ("almond_skinned.usdz", "almond", ForestOptions(trees=1, frames=48), True),
    ]
    with show_progress("demo", quiet) as bar:
        for k, (name, preset, options, skinned) in enumerate(jobs):
            bar.report("scenes", k, len(jobs), name)
            forest = generate_forest(load_preset(preset), 1, options)
            path = write_scene(forest, output / name, skinned=skinned)
            kind = "skinned + instanced" if skinned else "posed + instanced"
            bar.echo(
                f"{path}  {path.stat().st_size / 1e6:7.2f} MB  {preset}: {options.trees} "
                f"tree(s), {forest.n_instances} pieces, {options.frames} wind frame(s), {kind}"
            )
        bar("scenes", len(jobs), len(jobs))
        _demo_preview(output, bar)
    click.echo("open the scenes in usdview, Blender (File > Import > USD) or any USD tool")
    click.echo(
        "next: `forest presets` lists the species; `forest generate --preset oak --trees 3 "
        "-o oaks.usdz` grows three oaks; `forest --help` shows every command"
    )


def _demo_preview(folder: Path, bar: Quiet) -> None:
    """Render the demo forest with the worker's renderer; without the render extra or an EGL
    driver the scenes still stand, so say what is missing and go on."""
    from forest.extras import require
    from worker.render.render_file import RenderRequest, render_file  # GL loads on first use

    png, metrics = folder / "preview.png", folder / "metrics.json"
    try:
        require("render", "moderngl", path="")
        # staged (ground, sun shadows, MSAA, tone map): the picture a user judges the trees by.
        # One measured frame after the warm-up one: on a CPU rasteriser (llvmpipe) each
        # staged frame of this forest costs seconds of CPU time
        m = render_file(
            RenderRequest(
                scene=folder / "forest.usdc", output=png, metrics=metrics, frames=1, staged=True
            ),
            progress=bar,
        )
    except ForestError as exc:
        bar.echo(f"preview skipped: {exc}")
        return
    bar.echo(
        f"{png}  {m.width}x{m.height} staged, on {m.renderer}: {m.median.cpu_ms:.1f} ms per "
        f"frame (after a warm-up frame); figures in {metrics}"
    )


@bench.command("generate")
@click.option("--trees", type=int, default=10_000, show_default=True)
@click.option("--preset", default="alternating", show_default=True)
@click.option(
    "--recipe",
    help="Bench a mixed forest instead: its placement and growth, layer by layer, beside a "
    "single-species forest of as many trees (the recipe's first layer's species).",
)
@click.option("--repeat", type=int, default=3, show_default=True)
@input_errors
def bench_generate(trees: int, preset: str, recipe: str | None, repeat: int) -> None:
    """Pieces/s of expansion + assembly + pose + tiles against a per-piece Python loop, and
    seconds to write the forest as .usdc (or, with --recipe, a mixed forest's placement and
    growth beside a single-species forest)."""
    if recipe is not None:
        from bench.stand import run_stand_bench

        run_stand_bench(recipe, trees, repeat, echo=click.echo)
        return
    from bench.generate import run_generate_bench

    run_generate_bench(trees=trees, preset=preset, repeat=repeat, echo=click.echo)


@bench.command("export")
@click.option("--preset", default="oak", show_default=True)
@click.option("--trees", type=click.IntRange(1, 64), default=10, show_default=True)
@click.option("--frames", type=click.IntRange(0), default=24, show_default=True)
@click.option("--seed", type=int, default=3, show_default=True)
@input_errors
def bench_export(preset: str, trees: int, frames: int, seed: int) -> None:
    """One forest written as .usdc, .usdz and .glb (game and film profiles, each packing)
    and as posed .usdc: write seconds, bytes with pictures, joints and triangles per tree at
    every level of detail, measured from the files; each .glb's write time over the posed
    .usdc's; beside ez-tree's Oak Large GLB."""
    from bench.export import run_export_bench

    run_export_bench(preset, trees, frames, seed, echo=click.echo)


@bench.command("forest")
@click.option("--trees", type=click.IntRange(1), default=1_000_000, show_default=True)
@click.option(
    "--tile-size",
    type=FiniteRange(0, 1e6, min_open=True),
    default=250.0,
    show_default=True,
    help="Metres per tile.",
)
@click.option("--preset", default="alternating", show_default=True)
@click.option("--frames", type=click.IntRange(0), default=0, show_default=True)
@click.option(
    "--workers",
    default="1,2",
    show_default=True,
    help="Comma-separated worker process counts, each a run of its own.",
)
@click.option(
    "--area",
    type=(FiniteRange(0, 1e6, min_open=True), FiniteRange(0, 1e6, min_open=True)),
    metavar="W D",
    default=None,
    help="Width and depth in metres (default: trees 4 m apart).",
)
@input_errors
def bench_forest(
    trees: int,
    tile_size: float,
    preset: str,
    frames: int,
    workers: str,
    area: tuple[float, float] | None,
) -> None:
    """A tiled forest made by 1 and 2 worker processes (the farm's tile work in a process
    pool): wall time and ratio, peak RSS per worker, bytes per tree and per bone per frame,
    write time against the page-cache floor."""
    from bench.forest import run_forest_bench
    from forest.growth.presets import load_preset

    try:
        counts = [int(w) for w in workers.split(",")]
    except ValueError:
        raise ForestError(
            f"workers must be integers like 1,2, got {workers!r}", path="workers"
        ) from None
    if not counts or min(counts) < 1:
        raise ForestError(f"workers must be at least 1, got {workers!r}", path="workers")
    load_preset(preset)  # an unknown preset fails here, before any worker starts
    run_forest_bench(trees, tile_size, preset, frames, counts, area, echo=click.echo)
