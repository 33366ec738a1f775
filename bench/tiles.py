"""``forest bench tiles``: milliseconds per tile of the quilting stitch (error surfaces, the
minimum-error-cut dynamic programme, compositing), vectorised with numpy, next to the same
work written as plain Python loops, on the same inputs and in the same run; and the whole
tile-set build per tile. The baseline's tiles are checked to equal the vectorised ones."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from forest.bark.barkgen import bark_example
from forest.bark.images import ExampleImage
from forest.bark.quilting import min_cut_paths
from forest.bark.tileset import (
    TileGeometry,
    TileSet,
    band_errors,
    build_tileset,
    class_frame,
    default_classes,
    stitch_tiles,
)

Echo = Callable[[str], None]
T = TypeVar("T")
U8 = NDArray[np.uint8]


# ---------------------------------------------------------------- the plain-Python baseline


def min_cut_python(err: Sequence[Sequence[int]]) -> list[int]:
    """The minimum-error cut of one band, row by row and column by column in plain Python,
    with the tie rules of :func:`forest.bark.quilting.min_cut_paths`."""
    h, w = len(err), len(err[0])
    acc = list(err[0])
    moves: list[list[int]] = [[0] * w]
    for i in range(1, h):
        row_err = err[i]
        new, mv = [], []
        for j in range(w):
            best, m = acc[j], 0
            if j > 0 and acc[j - 1] < best:
                best, m = acc[j - 1], -1
            if j + 1 < w and acc[j + 1] < best:
                best, m = acc[j + 1], 1
            new.append(best + row_err[j])
            mv.append(m)
        acc = new
        moves.append(mv)
    j = min(range(w), key=acc.__getitem__)
    path = [0] * h
    path[h - 1] = j
    for i in range(h - 1, 0, -1):
        j += moves[i][j]
        path[i - 1] = j
    return path


def stitch_tile_python(frame: U8, patch: U8, geom: TileGeometry) -> U8:
    """One tile as :func:`forest.bark.tileset.stitch_tiles` makes it, pixel by pixel in Python."""
    s, w, o, e = geom.size, geom.border, geom.overlap, geom.extent
    f, p = frame.tolist(), patch.tolist()

    def at(img: list, side: int, i: int, j: int) -> list[int]:
        if side == 0:
            return img[i][w + j]
        if side == 1:
            return img[i][s - w - 1 - j]
        if side == 2:
            return img[w + j][i]
        return img[s - w - 1 - j][i]

    cuts = []
    for side in range(4):
        err = [
            [
                sum(
                    (a - b) * (a - b)
                    for a, b in zip(at(f, side, i, j), at(p, side, i, j), strict=True)
                )
                for j in range(o)
            ]
            for i in range(s)
        ]
        cuts.append(min_cut_python(err))
    left, right, top, bottom = cuts
    out = []
    for y in range(s):
        row = []
        for x in range(s):
            use_frame = (
                y < w
                or y >= s - w
                or x < w
                or x >= s - w
                or (x < e and x - w < left[y])
                or (x >= s - e and s - w - 1 - x < right[y])
                or (y < e and y - w < top[x])
                or (y >= s - e and s - w - 1 - y < bottom[x])
            )
            row.append(f[y][x] if use_frame else p[y][x])
        out.append(row)
    return np.array(out, np.uint8)


# ---------------------------------------------------------------- the benchmark


def _best(fn: Callable[[], T], repeat: int) -> tuple[float, T]:
    best = math.inf
    out = fn()  # warm-up run: first-touch page faults and imports are not the algorithm
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def procedural_examples(size: int, count: int = 2) -> list[ExampleImage]:
    """``count`` procedural bark examples of ``size x size`` pixels, in memory."""
    out = []
    for k in range(count):
        pixels = bark_example(size, size, seed=k + 1)
        out.append(
            ExampleImage(
                path=Path(f"procedural-bark-{k + 1}"),
                pixels=pixels,
                channels=3,
                format="uint8",
                sha256="0" * 64,
            )
        )
    return out


def stitch_inputs(tileset: TileSet, examples: Sequence[ExampleImage]) -> tuple[U8, U8]:
    """The frames and interior patches a built tile set was stitched from, ``(n, S, S, 3)``."""
    m = tileset.manifest
    s = int(m.tile_size or 0)
    geom = TileGeometry(s, int(m.border or 0), int(m.overlap or 0))
    by_id = {c.id: c for c in m.classes}
    frames, patches = [], []
    for r in m.tiles:
        edges = by_id[r.class_id].edges
        assert edges is not None
        p = tileset.patterns
        frames.append(
            class_frame(p[edges.left], p[edges.right], p[edges.top], p[edges.bottom], geom)
        )
        patches.append(examples[r.source].pixels[r.y : r.y + s, r.x : r.x + s])
    return np.stack(frames), np.stack(patches)


def run_tiles_bench(
    size: int = 256, tiles: int = 16, repeat: int = 3, baseline_tiles: int = 2, echo: Echo = print
) -> dict[str, float]:
    geom = TileGeometry.for_size(size)
    examples = procedural_examples(3 * size)
    classes = default_classes(tiles - tiles // 2, tiles // 2)
    t_build, tileset = _best(lambda: build_tileset(examples, classes, geom, 1), repeat)
    frames, patches = stitch_inputs(tileset, examples)
    n = len(frames)
    t_vec, (vec_tiles, _) = _best(lambda: stitch_tiles(frames, patches, geom), repeat)
    assert np.array_equal(vec_tiles, tileset.tiles)

    def one_at_a_time() -> None:
        for i in range(n):
            stitch_tiles(frames[i : i + 1], patches[i : i + 1], geom)

    t_single, _ = _best(one_at_a_time, repeat)
    nb = max(1, min(baseline_tiles, n))
    t_base = math.inf
    for _ in range(2):  # slow: best of two, no warm-up
        t0 = time.perf_counter()
        base_tiles = [stitch_tile_python(frames[i], patches[i], geom) for i in range(nb)]
        t_base = min(t_base, time.perf_counter() - t0)
    if not np.array_equal(np.stack(base_tiles), vec_tiles[:nb]):
        raise AssertionError("the plain-Python baseline and the vectorised stitch disagree")

    err = band_errors(frames, patches, geom)  # (n, 4, S, o)
    t_dp, _ = _best(lambda: min_cut_paths(err), repeat)
    lists = [[band.tolist() for band in err[i]] for i in range(nb)]

    def dp_baseline() -> None:
        for bands in lists:
            for band in bands:
                min_cut_python(band)

    t_dp_base, _ = _best(dp_baseline, repeat)

    ms = {
        "build": 1e3 * t_build / n,
        "stitch": 1e3 * t_vec / n,
        "stitch_single": 1e3 * t_single / n,
        "stitch_baseline": 1e3 * t_base / nb,
        "dp": 1e3 * t_dp / n,
        "dp_baseline": 1e3 * t_dp_base / nb,
    }
    counts = ", ".join(f"{c.count} {c.name}" for c in classes)
    echo(
        f"{n} tiles of {size} px ({counts}; border {geom.border}, cut band {geom.overlap}) from "
        f"{len(examples)} procedural bark examples of {3 * size} px; best of {repeat} after a "
        "warm-up run (the stitch baseline: best of two)"
    )
    echo(f"{'':52}{'tiles':>6}{'ms/tile':>10}")
    rows = [
        ("whole build (patterns, patch choice, stitch)", n, ms["build"]),
        ("stitch, vectorised (all tiles in one batch)", n, ms["stitch"]),
        ("stitch, vectorised (one tile per call)", n, ms["stitch_single"]),
        ("stitch, baseline (plain Python loops)", nb, ms["stitch_baseline"]),
        ("min-cut DP alone, vectorised (one batch)", n, ms["dp"]),
        ("min-cut DP alone, baseline (plain Python loops)", nb, ms["dp_baseline"]),
    ]
    for label, count, value in rows:
        echo(f"{label:52}{count:>6}{value:>10.2f}")
    speed = ms["stitch_baseline"] / ms["stitch"]
    speed_single = ms["stitch_baseline"] / ms["stitch_single"]
    speed_dp = ms["dp_baseline"] / ms["dp"]
    echo(
        f"speed-up over the baseline: stitch {speed:.0f}x batched, {speed_single:.0f}x one tile "
        f"per call; DP alone {speed_dp:.0f}x   (targets: < 50 ms per tile, >= 50x)"
    )
    ms.update(speedup=speed, speedup_single=speed_single, speedup_dp=speed_dp)
    return ms
