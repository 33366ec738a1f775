"""``forest bench forest``: a tiled forest generated and written by 1, 2, ... worker processes,
each tile as the farm makes it (:func:`worker.jobs.tile.run_tile`'s work: ``generate_tile`` then
``write_tile_file``), then the root layer. Workers are a process pool over that tile
function, not Celery workers on a broker: the figures are the tiles' own work, with no
queueing or artifact copies in them.

Per worker count: wall time, peak RSS of each worker process, and the files' bytes per tree
per frame; per bone per frame, what one frame of ``forest:jointRotations`` stores; and the
tiles' write time against the page-cache floor for the same bytes
(:mod:`bench.floor`)."""

from __future__ import annotations

import math
import multiprocessing
import os
import resource
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from bench.floor import page_cache_write_seconds, timed_saves
from forest.growth.generate import ForestOptions
from forest.growth.tiling import TilePlan
from forest.usd.tiled import TileEntry

Echo = Callable[[str], None]
SPACING = 4.0  # metres between neighbouring trees when no area is given


@dataclass(frozen=True)
class TileJob:
    preset: str
    plan: TilePlan
    i: int
    j: int
    frames: int
    folder: str


@dataclass(frozen=True)
class TileResult:
    pid: int
    trees: int
    pieces: int
    bones: int
    rotations: int  # rows of one forest:jointRotations sample (turning bones)
    bytes: int
    generate_s: float
    write_s: float
    save_s: float
    max_rss: int  # bytes: the worker process's peak so far
    entry: TileEntry


@dataclass
class Run:
    workers: int
    wall_s: float
    tiles: list[TileResult] = field(default_factory=list)

    def total(self, name: str) -> float:
        return float(sum(getattr(t, name) for t in self.tiles))

    def peak_rss(self) -> dict[int, int]:
        """Each worker process's peak RSS, bytes."""
        peaks: dict[int, int] = {}
        for t in self.tiles:
            peaks[t.pid] = max(peaks.get(t.pid, 0), t.max_rss)
        return peaks


def _start_worker() -> None:
    from forest.memory import keep_freed_memory

    keep_freed_memory()  # as `forest worker` does (the CLI sets it for every command)


def run_tile_job(job: TileJob) -> TileResult:
    """One tile, as the farm's tile task makes it: generate, write, extent."""
    from pxr import Sdf

    from forest.growth.presets import load_preset
    from forest.growth.tiling import generate_tile, tile_name
    from forest.usd.contract import JOINT_ROTATIONS, PIECES
    from forest.usd.tiled import write_tile_file

    grammar = load_preset(job.preset)
    options = ForestOptions(frames=job.frames)
    t0 = time.perf_counter()
    forest = generate_tile(grammar, job.plan, job.i, job.j, options)
    t1 = time.perf_counter()
    name = f"{tile_name(job.i, job.j)}.usdc"
    path = Path(job.folder) / name
    with timed_saves() as saves:  # the scene, then its extent read back, as the farm does
        entry = write_tile_file(forest, path, f"./{tiles_asset(job.folder)}/{name}", job.i, job.j)
    t2 = time.perf_counter()
    rotations = 0
    if forest is not None and job.frames:
        layer = Sdf.Layer.FindOrOpen(str(path))
        spec = layer.GetAttributeAtPath(f"{PIECES}.{JOINT_ROTATIONS}")
        sample = layer.QueryTimeSample(spec.path, 0.0) if spec else None
        rotations = 0 if sample is None else len(sample)
    return TileResult(
        pid=os.getpid(),
        trees=0 if forest is None else forest.options.trees,
        pieces=0 if forest is None else forest.n_instances,
        bones=0 if forest is None else len(forest.bones),
        rotations=rotations,
        bytes=path.stat().st_size,
        generate_s=t1 - t0,
        write_s=t2 - t1,
        save_s=sum(saves),
        max_rss=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        entry=entry,
    )


def tiles_asset(folder: str) -> str:
    return Path(folder).name


def run_forest(preset: str, plan: TilePlan, frames: int, workers: int, folder: Path) -> Run:
    """Every tile of ``plan`` by a pool of ``workers`` fresh processes, then the root layer."""
    from forest.usd.tiled import write_root

    tiles = folder / "forest_tiles"
    tiles.mkdir(parents=True)
    jobs = [TileJob(preset, plan, i, j, frames, str(tiles)) for i, j in plan.tiles()]
    ctx = multiprocessing.get_context("spawn")  # fresh processes: their RSS is their own
    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_start_worker) as pool:
        results = list(pool.map(run_tile_job, jobs))
    write_root(folder / "forest.usda", [r.entry for r in results], frames=frames, meta=plan.meta())
    return Run(workers, time.perf_counter() - t0, results)


def run_forest_bench(
    trees: int,
    tile_size: float,
    preset: str = "alternating",
    frames: int = 0,
    workers: Sequence[int] = (1, 2),
    area: tuple[float, float] | None = None,
    folder: Path | None = None,
    echo: Echo = print,
) -> dict[str, object]:
    side = SPACING * math.sqrt(trees)
    plan = TilePlan(trees, area or (side, side), tile_size, seed=1)
    base = Path(tempfile.mkdtemp(prefix="forest-bench-", dir=folder))
    load = os.getloadavg()
    echo(
        f"preset {preset}, {trees} trees over {plan.area[0]:.0f} x {plan.area[1]:.0f} m, "
        f"{frames} frame(s), {plan.nx} x {plan.nz} tiles of {tile_size:g} m; "
        f"{os.cpu_count()} CPUs, load average {load[0]:.2f} at the start"
    )
    runs: list[Run] = []
    floor_s = 0.0
    try:
        for w in workers:
            out = base / f"w{w}"
            run = run_forest(preset, plan, frames, w, out)
            runs.append(run)
            if w == workers[0]:  # the floor for the same bytes, in the same folder
                floor_s = page_cache_write_seconds(out, int(run.total("bytes")))
            shutil.rmtree(out)  # a million trees are tens of GB: one run's files at a time
            peaks = run.peak_rss()
            echo(
                f"{w} worker(s): {run.wall_s:8.1f} s wall, {trees / run.wall_s:8.0f} trees/s; "
                f"peak RSS per worker {', '.join(f'{p / 2**30:.2f}' for p in peaks.values())} GiB"
            )
    finally:
        shutil.rmtree(base, ignore_errors=True)
    first = runs[0]
    pieces, bones = first.total("pieces"), first.total("bones")
    nbytes = first.total("bytes")
    per_frame = max(frames, 1)
    echo(
        f"{int(pieces)} pieces, {int(bones)} bones, {nbytes / 1e9:.2f} GB: "
        f"{nbytes / trees / per_frame:,.0f} bytes per tree per frame"
        + ("" if frames else " (a still forest: one frame)")
    )
    rotations = first.total("rotations")
    if frames:
        echo(
            f"wind: {16 * rotations / bones:.2f} bytes per bone per frame "
            "(float32 quaternions of the turning bones; target <= 16)"
        )
    write_s, save_s = first.total("write_s"), first.total("save_s")
    echo(
        f"{first.workers} worker(s): generate {first.total('generate_s'):.1f} s, "
        f"write {write_s:.1f} s "
        f"(Save {save_s:.1f} s); page-cache floor for the same bytes {floor_s:.2f} s: "
        f"write {write_s / floor_s:.1f}x, Save {save_s / floor_s:.1f}x the floor"
    )
    for run in runs[1:]:
        echo(
            f"{run.workers} workers against {first.workers}: {first.wall_s / run.wall_s:.2f}x "
            "(target >= 1.6x with 2)"
        )
    echo(f"load average at the end {os.getloadavg()[0]:.2f}")
    return {
        "trees": trees,
        "pieces": pieces,
        "bones": bones,
        "bytes": nbytes,
        "wall_s": {r.workers: r.wall_s for r in runs},
        "peak_rss": {r.workers: list(r.peak_rss().values()) for r in runs},
        "bytes_per_tree_frame": nbytes / trees / per_frame,
        "bytes_per_bone_frame": 16 * rotations / bones if frames and bones else None,
        "write_s": write_s,
        "save_s": save_s,
        "floor_s": floor_s,
    }
