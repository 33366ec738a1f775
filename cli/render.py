"""Commands that draw scenes: ``render``, ``inspect``, ``bench render``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from cli.app import bench, input_errors, main, needs, parse_counts
from cli.progress import quiet_option, show_progress
from forest.errors import ForestError, OutputError
from forest.sniff import USD_READERS, require_usd

VIEW_NAMES = ("overview", "side", "eye")  # worker.render.camera.VIEWS, without importing the worker


def parse_point(text: str | None, path: str) -> tuple[float, float, float] | None:
    """``"1,2.5,-3"`` -> ``(1.0, 2.5, -3.0)``; anything else is an input error naming ``path``."""
    if text is None:
        return None
    try:
        x, y, z = (float(v) for v in text.split(","))
    except ValueError:
        raise ForestError(f"expected X,Y,Z in metres, got {text!r}", path=path) from None
    return x, y, z


def camera_options(fn: Any) -> Any:
    """The camera and staging options shared by ``render`` (see worker.render.camera.CameraSpec)."""
    options = [
        click.option(
            "--view",
            type=click.Choice(VIEW_NAMES),
            default="overview",
            show_default=True,
            help="overview: the whole forest from 35 deg azimuth, 18 deg up; side: horizontal "
            "at mid-height; eye: eyes 1.7 m above the ground (at --distance).",
        ),
        click.option("--eye", "eye_text", metavar="X,Y,Z", help="Camera position, metres, Y up."),
        click.option("--target", "target_text", metavar="X,Y,Z", help="Point looked at."),
        click.option(
            "--fov", type=float, default=40.0, show_default=True, help="Vertical field, degrees."
        ),
        click.option("--distance", type=float, help="Eye view: metres from the forest's centre."),
        click.option(
            "--tree",
            "tree_index",
            type=int,
            metavar="N",
            help="Frame tree N of the scene alone (a close-up) in the view, not the forest.",
        ),
        click.option(
            "--bare",
            is_flag=True,
            help="No ground, sky, sun shadows, MSAA or tone map: the paper's measurement set-up "
            "(the default is staged: ground and sky with sun shadows, 4x MSAA and a filmic "
            "tone map).",
        ),
        click.option(
            "--ground",
            is_flag=True,
            help="The bare mode with a ground under the trees and a sky gradient (no shadows, "
            "MSAA or tone map).",
        ),
        # the default now; still accepted, as scripts name it
        click.option("--staged", is_flag=True, hidden=True),
    ]
    for option in reversed(options):
        fn = option(fn)
    return fn


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
@click.option(
    "--no-cull",
    is_flag=True,
    help="Send every instance and patch through the pipeline, out of view or not (comparison).",
)
@click.option(
    "--lod-pixels",
    type=click.FloatRange(0, 64),
    default=0.5,
    show_default=True,
    help="Skip pieces thinner on screen than this many pixels (far twigs); 0 draws every "
    "piece in view.",
)
@click.option("--no-foliage", is_flag=True, help="Leave the leaf clouds out.")
@click.option(
    "--foliage-geometry",
    is_flag=True,
    help="Draw the real leaf-cloud mesh at every cloud instead of 2.5D impostors (comparison).",
)
@click.option(
    "--clip",
    type=click.Path(path_type=Path),
    help="Also write the frames as a clip: .mp4, .webm, .gif or .webp. Without --frames, "
    "the scene's whole wind loop (it loops seamlessly).",
)
@click.option("--orbit", is_flag=True, help="Turn the camera once about its target over the clip.")
@click.option("--fps", type=float, help="The clip's frame rate (default: the scene's).")
@camera_options
@quiet_option
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
    lod_pixels: float = 0.5,
    no_foliage: bool = False,
    foliage_geometry: bool = False,
    view: str = "overview",
    eye_text: str | None = None,
    target_text: str | None = None,
    fov: float = 40.0,
    distance: float | None = None,
    tree_index: int | None = None,
    bare: bool = False,
    ground: bool = False,
    staged: bool = False,
    clip: Path | None = None,
    orbit: bool = False,
    fps: float | None = None,
    quiet: bool = False,
) -> None:
    """Render a forest scene offscreen (EGL) to a preview PNG, with frame-time metrics; staged
    (ground, sun shadows, MSAA, tone map) unless --bare or --ground."""
    require_usd(scene, USD_READERS["render"])
    # a clip goes through imageio: ffmpeg for mp4 and webm, Pillow for gif and webp
    needs("render", "moderngl", *(("imageio", "imageio_ffmpeg", "PIL") if clip else ()))
    from worker.render.camera import CameraSpec
    from worker.render.render_file import RenderRequest, render_file

    if staged and (bare or ground):
        other = "--bare" if bare else "--ground"
        raise ForestError(f"--staged and {other} ask for two looks: give one", path="staged")

    spec = CameraSpec(
        view=view,
        eye=parse_point(eye_text, "eye"),
        target=parse_point(target_text, "target"),
        fov=fov,
        distance=distance,
        tree=tree_index,
    )

    request = RenderRequest(
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
        lod_pixels=lod_pixels,
        foliage=None if no_foliage else "geometry" if foliage_geometry else "impostor",
        camera=spec,
        ground=ground,
        staged=not (bare or ground),
        clip=clip,
        orbit=orbit,
        fps=fps,
    )
    with show_progress("render", quiet) as bar:
        m = render_file(request, progress=bar)
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
    if clip is not None:
        click.echo(f"wrote {clip}: {len(m.frames)} frame(s)")
    if metrics is not None:
        click.echo(f"wrote {metrics}")


@main.command()
@click.argument("scene", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), help="Contact sheet PNG.")
@click.option("--frame", type=int, default=0, show_default=True, help="Palette (wind) sample.")
@click.option("--width", type=click.IntRange(200, 8192), default=1400, show_default=True)
@click.option("--height", type=click.IntRange(150, 8192), default=1050, show_default=True)
@click.option(
    "--figures",
    is_flag=True,
    help="Print per-tree figures measured from the USD alone: height, leaf cards, lowest "
    "bark and leaf vertex, twig tip diameters, crown plan and base, triangles.",
)
@input_errors
def inspect(
    scene: Path, output: Path | None, frame: int, width: int, height: int, figures: bool
) -> None:
    """Diagnostic contact sheet (pyvista, offscreen): skeleton, rims and tile classes, tile
    indices, piece types; with --figures, a table of each tree's figures."""
    require_usd(scene, USD_READERS["inspect"])
    if output is None and not figures:
        raise ForestError(
            "give -o SHEET.png for the contact sheet, --figures for the figures, or both",
            path="forest inspect",
        )
    if output is not None:  # the sheet's checks first: a bad -o does no work
        needs("inspect", "pyvista", "vtk")
        if output.suffix.lower() != ".png":
            raise OutputError("the contact sheet is a PNG: name it *.png", path=str(output))
        if not output.parent.resolve().is_dir():
            raise OutputError("folder does not exist", path=str(output))
    if figures:
        from forest.usd.figures import figures_table, scene_figures

        fig = scene_figures(scene)
        click.echo(f"{scene}: {len(fig.trees)} tree(s), measured on the {fig.representation} form")
        click.echo(figures_table(fig.trees))
    if output is None:
        return
    from cli.sheets.inspect import contact_sheet
    from forest.usd.read import read_scene

    s = read_scene(scene)
    if not 0 <= frame < s.n_frames:
        raise ForestError(
            f"the scene has {s.n_frames} palette sample(s), got {frame}", path="frame"
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
    "--no-staged", is_flag=True, help="Skip the staged mode (shadows, MSAA, tone map) rows."
)
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
    no_staged: bool = False,
    foliage_text: str = "none",
) -> None:
    """Frame time against tree count, instanced against one draw call per piece, at fixed
    tessellation levels (the paper's Figure 16 and its levels 1 and 10), in the bare mode;
    the staged mode (ground, sun shadows, 4x MSAA, tone map) instanced beside it; each also
    with the cull pass and sub-pixel LOD that `forest render` uses (modes lod, staged_lod)."""
    needs("render", "moderngl", "matplotlib")
    from bench.render import run_render_bench

    try:
        levels = [float(x) for x in levels_text.split(",") if x.strip()]
    except ValueError:
        raise ForestError(f"expected numbers, got {levels_text!r}", path="levels") from None
    if not levels or not all(1.0 <= lv <= 64.0 for lv in levels):
        raise ForestError("levels must be in [1, 64]", path="levels")
    run_render_bench(
        parse_counts(trees_text, "trees"),
        levels,
        preset=preset,
        size=(width, height),
        frames=frames,
        naive=not no_naive,
        staged=not no_staged,
        plot=plot,
        echo=click.echo,
        foliage_trees=(
            [] if foliage_text.strip() == "none" else parse_counts(foliage_text, "foliage_trees")
        ),
    )
