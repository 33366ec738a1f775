"""``forest bench render``: frame time against tree count (the paper's Figure 16), instanced
(one draw call per piece type) side by side with the naive way (one draw call per piece
instance), at fixed tessellation levels (1 and 10 by default, as the paper measured), in the
bare mode (no ground, shadows or MSAA: the paper's set-up); the staged mode (mode ``staged``:
ground, the sun's shadow pass, 4x MSAA, the tone map) instanced beside it. Modes ``lod`` and
``staged_lod`` are the same with the per-instance cull pass (worker.render.instance_cull: instances
out of view, and pieces thinner on screen than DEFAULT_LOD_PIXELS, are not drawn), as ``forest
render`` draws by default; ``drawn`` is the instances it kept.

Each forest is generated, written as ``.usdc`` and read back, so the renderer sees exactly
what a worker gets. The level is the same on every edge (no distance falloff), so triangles
per frame are ``2 * level^2`` per quad. Frame time is the wall time around a finished frame
(glFinish) at the median of the measured frames; GPU timer-query times are printed beside it,
but on a CPU rasteriser such as llvmpipe they bracket command submission only.

Foliage (paper 6): for the ``foliage_trees`` counts, the same frame (branches at level 1) with
every leaf cloud drawn as 2.5D impostors (both passes every frame, as when the camera turns)
next to the real leaf-cloud mesh instanced at the same positions: frame time and triangles
side by side.
"""

from __future__ import annotations

import math
import statistics
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from forest.bark.tile_folder import TileImages
from forest.gl.context import create_context, gl_info, raise_gl_error
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.usd.read import SceneArrays, read_scene
from forest.usd.scene import write_scene
from schemas.grammar import Grammar
from worker.render.foliage import FOLIAGE_MODES
from worker.render.instance_cull import DEFAULT_LOD_PIXELS
from worker.render.render_file import preview_view
from worker.render.renderer import Renderer, TessSettings
from worker.render.staging import STAGED
from worker.render.textures import procedural_tiles

if TYPE_CHECKING:
    import moderngl

Echo = Callable[[str], None]
# the modes with the cull pass, and the mode each is compared with
LOD_BASE = {"lod": "instanced", "staged_lod": "staged"}
SPACING = 6.0  # metres between trees: the area grows with the tree count
# the paper's Figure 16 (DirectX 11, no animation), milliseconds per frame
PAPER = {
    "GTX 980 Ti": {1: 0.5319, 10: 0.9523, 50: 3.5714, 100: 6.25, 250: 17.5439, 500: 28.5714,
                   1000: 58.8235},
    "GTX 950M": {1: 3.125, 10: 4.3478, 50: 11.1111, 100: 25.0, 250: 38.4615, 500: 83.3333,
                 1000: 166.6667},
}  # fmt: skip


@dataclass(frozen=True)
class BenchRow:
    trees: int
    pieces: int
    level: float
    mode: str  # "instanced", "per_instance" (bare: the paper's set-up), "staged", "lod"...
    draw_calls: int
    triangles: int
    cpu_ms: float
    gpu_ms: float | None
    drawn: int | None = None  # instances kept by the cull pass (lod modes)


def _bench_scene(grammar: Grammar, n: int, path: Path) -> tuple[SceneArrays, TileImages]:
    """``n`` trees at the bench's density, through a written and re-read scene (what a render
    job sees), with the placeholder tiles."""
    side = SPACING * math.sqrt(n)
    forest = generate_forest(grammar, 1, ForestOptions(trees=n, area=(side, side)))
    scene = read_scene(write_scene(forest, path, skinned=False))  # read back only
    return scene, procedural_tiles(scene.manifest, scene.manifest.n_slices)


def run_render_bench(
    trees: Sequence[int],
    levels: Sequence[float] = (1.0, 10.0),
    preset: str = "alternating",
    size: tuple[int, int] = (320, 240),
    frames: int = 3,
    naive: bool = True,
    plot: Path | None = None,
    echo: Echo = print,
    foliage_trees: Sequence[int] = (),
    foliage_rows: list[FoliageBenchRow] | None = None,
    staged: bool = True,
) -> list[BenchRow]:
    """Branches: instanced against a draw call per piece (no foliage), in the bare mode (no
    ground, shadows or MSAA: the paper's Figure 16 set-up); with ``staged`` also instanced in
    the staged mode (worker.render.staging.STAGED: ground, sun shadow pass, 4x MSAA, tone map)
    beside it. Then, for each of ``foliage_trees``, impostor foliage against the real
    leaf-cloud geometry (rows appended to ``foliage_rows`` when given)."""
    ctx = create_context()
    info = gl_info(ctx)
    echo(f"renderer: {info.renderer} ({info.version})")
    if info.software:
        echo("note: a CPU rasteriser: frame times measure the CPU, not a GPU")
    grammar = load_preset(preset)
    rows: list[BenchRow] = []
    header = (
        f"{'trees':>6} {'pieces':>7} {'level':>5} {'mode':>12} {'draws':>6} "
        f"{'triangles':>11} {'frame ms':>9} {'gpu ms':>8} {'drawn':>8}"
    )
    echo(header)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for n in trees:
                scene, images = _bench_scene(grammar, n, Path(tmp) / f"bench_{n}.usdc")
                renderer = Renderer(ctx, scene, size, images, foliage=None)
                staged_renderer = (
                    Renderer(ctx, scene, size, images, foliage=None, staging=STAGED)
                    if staged
                    else None
                )
                try:
                    camera, _ = preview_view(scene, size, 1.0, foliage=False)
                    for level in levels:
                        tess = TessSettings(max_level=level, lod_half=0.0)
                        modes = ["instanced", "per_instance"] if naive else ["instanced"]
                        modes.append("lod")
                        for mode in modes + (["staged", "staged_lod"] if staged else []):
                            r = staged_renderer if mode.startswith("staged") else renderer
                            assert r is not None
                            per_instance = mode == "per_instance"
                            lod = DEFAULT_LOD_PIXELS if mode in LOD_BASE else None
                            r.draw(camera, tess, per_instance=per_instance, lod_pixels=lod)
                            stats = [
                                r.draw(camera, tess, per_instance=per_instance, lod_pixels=lod)
                                for _ in range(frames)
                            ]
                            gpu = [s.gpu_ms for s in stats if s.gpu_ms is not None]
                            row = BenchRow(
                                trees=n,
                                pieces=scene.n_instances,
                                level=level,
                                mode=mode,
                                draw_calls=stats[0].draw_calls,
                                triangles=stats[0].primitives,
                                cpu_ms=statistics.median(s.cpu_ms for s in stats),
                                gpu_ms=statistics.median(gpu) if len(gpu) == len(stats) else None,
                                drawn=stats[0].drawn_instances,
                            )
                            rows.append(row)
                            g = f"{row.gpu_ms:8.2f}" if row.gpu_ms is not None else f"{'-':>8}"
                            d = f"{row.drawn:>8}" if row.drawn is not None else f"{'-':>8}"
                            echo(
                                f"{n:>6} {row.pieces:>7} {level:>5g} {row.mode:>12} "
                                f"{row.draw_calls:>6} {row.triangles:>11} {row.cpu_ms:>9.2f} "
                                f"{g} {d}"
                            )
                    raise_gl_error(ctx, f"the {n}-tree forest")
                finally:
                    renderer.release()
                    if staged_renderer is not None:
                        staged_renderer.release()
            if foliage_trees:
                found = _foliage_bench(ctx, foliage_trees, preset, size, frames, Path(tmp), echo)
                if foliage_rows is not None:
                    foliage_rows.extend(found)
    finally:
        ctx.release()
    _summary(rows, echo)
    if plot is not None:
        plot_rows(rows, plot, info.renderer)
        echo(f"wrote {plot}")
    return rows


@dataclass(frozen=True)
class FoliageBenchRow:
    trees: int
    clouds: int
    mode: str  # "impostor" (both passes every frame) or "geometry"
    draw_calls: int  # the whole frame
    triangles: int  # the whole frame
    foliage_triangles: int  # the foliage passes alone
    cpu_ms: float
    gpu_ms: float | None
    foliage_ms: float  # frames of the foliage alone (no branches)


def _foliage_bench(
    ctx: moderngl.Context,
    trees: Sequence[int],
    preset: str,
    size: tuple[int, int],
    frames: int,
    tmp: Path,
    echo: Echo,
) -> list[FoliageBenchRow]:
    """Frames of the branches (tessellation level 1) plus every leaf cloud, as impostors (pass 1
    forced every frame, as when the camera turns) or as the real leaf-cloud mesh."""
    grammar = load_preset(preset)
    if not grammar.foliage:
        echo(f"note: preset {preset} bears no foliage: no foliage rows")
        return []
    echo("foliage: impostors (pass 1 every frame) against the real leaf-cloud mesh")
    echo(
        f"{'trees':>6} {'clouds':>7} {'mode':>9} {'draws':>6} {'triangles':>11} "
        f"{'foliage tri':>11} {'frame ms':>9} {'gpu ms':>8} {'foliage ms':>10}"
    )
    rows: list[FoliageBenchRow] = []
    tess = TessSettings(max_level=1.0, lod_half=0.0)
    for n in trees:
        scene, images = _bench_scene(grammar, n, tmp / f"foliage_{n}.usdc")
        camera, _ = preview_view(scene, size, 1.0)
        by_mode: dict[str, FoliageBenchRow] = {}
        for mode in FOLIAGE_MODES:
            renderer = Renderer(ctx, scene, size, images, foliage=mode)
            try:
                renderer.draw(camera, tess, force_impostor=True)  # warm-up
                stats = [renderer.draw(camera, tess, force_impostor=True) for _ in range(frames)]
                alone = [
                    renderer.draw(camera, tess, force_impostor=True, branches=False)
                    for _ in range(frames)
                ]
                raise_gl_error(ctx, f"the {n}-tree forest's foliage")
            finally:
                renderer.release()
            gpu = [s.gpu_ms for s in stats if s.gpu_ms is not None]
            f0 = stats[0].foliage
            row = FoliageBenchRow(
                trees=n,
                clouds=scene.n_foliage,
                mode=mode,
                draw_calls=stats[0].draw_calls,
                triangles=stats[0].primitives,
                foliage_triangles=f0.primitives if f0 is not None else 0,
                cpu_ms=statistics.median(s.cpu_ms for s in stats),
                gpu_ms=statistics.median(gpu) if len(gpu) == len(stats) else None,
                foliage_ms=statistics.median(s.cpu_ms for s in alone),
            )
            rows.append(row)
            by_mode[mode] = row
            g = f"{row.gpu_ms:8.2f}" if row.gpu_ms is not None else f"{'-':>8}"
            echo(
                f"{n:>6} {row.clouds:>7} {mode:>9} {row.draw_calls:>6} {row.triangles:>11} "
                f"{row.foliage_triangles:>11} {row.cpu_ms:>9.2f} {g} {row.foliage_ms:>10.2f}"
            )
        imp, geo = by_mode["impostor"], by_mode["geometry"]
        if imp.cpu_ms > 0 and imp.foliage_ms > 0 and imp.foliage_triangles > 0:
            echo(
                f"{n} trees: with impostors a frame is {geo.cpu_ms / imp.cpu_ms:.2f}x as fast "
                f"(foliage alone {geo.foliage_ms / imp.foliage_ms:.2f}x) as with the real leaf "
                f"clouds, for {geo.foliage_triangles / imp.foliage_triangles:.0f}x fewer "
                "foliage triangles"
            )
    return rows


def _summary(rows: list[BenchRow], echo: Echo) -> None:
    by = {(r.trees, r.level, r.mode): r for r in rows}
    for r in rows:
        naive = by.get((r.trees, r.level, "per_instance"))
        if r.mode == "instanced" and naive is not None and r.cpu_ms > 0:
            echo(
                f"{r.trees} trees, level {r.level:g}: instanced is {naive.cpu_ms / r.cpu_ms:.2f}x "
                f"the speed of one draw call per piece ({r.draw_calls} vs {naive.draw_calls} calls)"
            )
    for r in rows:
        plain = by.get((r.trees, r.level, LOD_BASE.get(r.mode, "")))
        if plain is not None and r.cpu_ms > 0 and r.drawn is not None:
            echo(
                f"{r.trees} trees, level {r.level:g}, {plain.mode}: the cull pass draws "
                f"{r.drawn} of {r.pieces} pieces, {plain.cpu_ms / r.cpu_ms:.2f}x the speed"
            )


def plot_rows(rows: list[BenchRow], path: Path, renderer: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5), dpi=110)
    series = sorted({(r.mode, r.level) for r in rows})
    for mode, level in series:
        pts = sorted((r.trees, r.cpu_ms) for r in rows if (r.mode, r.level) == (mode, level))
        name = {
            "instanced": "instanced",
            "per_instance": "draw per piece",
            "lod": f"instanced, cull + {DEFAULT_LOD_PIXELS:g} px LOD",
        }.get(mode, mode)
        label = f"{name}, level {level:g}"
        style = {"instanced": "-o", "per_instance": "--s", "lod": "-.d"}.get(mode, ":^")
        ax.plot(*zip(*pts, strict=True), style, label=label)
    for (gpu, values), style in zip(PAPER.items(), (":", "-."), strict=True):
        pts = sorted(values.items())
        ax.plot(*zip(*pts, strict=True), style, color="grey", alpha=0.8, label=f"paper, {gpu}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("trees")
    ax.set_ylabel("frame time, ms (median)")
    ax.set_title(f"forest bench render: {renderer}", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
