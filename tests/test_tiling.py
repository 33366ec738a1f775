"""Tiled forests (issue 12.1): seamless placement across tile edges, tile files independent of
the order they are written in, a root layer whose payloads open unloaded, the CLI."""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from pxr import Usd

from cli import main
from forest.errors import ForestError, LimitError
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.presets import load_preset
from forest.growth.tiling import TilePlan, generate_tile
from forest.usd.contract import TILES
from forest.usd.tiled import tiles_folder, write_root, write_tile

GRAMMAR = load_preset("almond")
SCALE = (GRAMMAR.trunk_radius, GRAMMAR.tree_scale)


def union(plan: TilePlan) -> tuple[np.ndarray, np.ndarray]:
    cells, ms = [], []
    thr = plan.threshold()
    for i, j in plan.tiles():
        c, m = plan.tile_trees(i, j, *SCALE, threshold=thr)
        x0, x1, z0, z1 = plan.rect(i, j)
        x = m[:, 0, 3] + plan.area[0] / 2
        z = m[:, 2, 3] + plan.area[1] / 2
        assert np.all((x >= x0) & (x <= x1) & (z >= z0) & (z <= z1))  # each in its own tile
        cells.append(c)
        ms.append(m)
    c, m = np.concatenate(cells), np.concatenate(ms)
    order = np.argsort(c)
    return c[order], m[order]


@settings(max_examples=25, deadline=None)
@given(
    trees=st.integers(1, 3000),
    width=st.floats(5, 400),
    depth=st.floats(5, 400),
    tile=st.floats(3, 150),
    seed=st.integers(0, 2**63 - 1),
)
def test_tiles_union_equals_one_tile(
    trees: int, width: float, depth: float, tile: float, seed: int
) -> None:
    plan = TilePlan(trees, (width, depth), tile, seed)
    whole = TilePlan(trees, (width, depth), max(width, depth) * 2, seed)
    assert (whole.nx, whole.nz) == (1, 1)
    c, m = union(plan)
    c1, m1 = whole.tile_trees(0, 0, *SCALE)
    assert len(c) == trees and len(np.unique(c)) == trees  # no gap, no tree twice
    np.testing.assert_array_equal(c, c1)
    np.testing.assert_array_equal(m, m1)  # bit for bit: same positions, headings, scales
    if trees > 1:  # spacing held across tile edges too
        xz = m[:, [0, 2], 3]
        d = np.linalg.norm(xz[:, None] - xz[None], axis=-1) if trees <= 800 else None
        if d is not None:
            np.fill_diagonal(d, np.inf)
            assert d.min() >= plan.min_spacing() * (1 - 1e-9)


def test_plan_errors_name_the_field() -> None:
    with pytest.raises(ForestError, match="tile_size"):
        TilePlan(10, (10.0, 10.0), 0.0, 0)
    with pytest.raises(LimitError, match="tile_size"):
        TilePlan(10, (1e5, 1e5), 1.0, 0)  # 1e10 tiles
    with pytest.raises(LimitError, match="trees"):
        TilePlan(0, (10.0, 10.0), 5.0, 0)
    with pytest.raises(LimitError, match=r"area\.depth"):
        TilePlan(10, (10.0, float("nan")), 5.0, 0)


def test_million_tree_plan_is_cheap() -> None:
    plan = TilePlan(1_000_000, (5000.0, 5000.0), 250.0, 3)
    thr = plan.threshold()
    c, _ = plan.tile_trees(7, 11, *SCALE, threshold=thr)
    assert 2000 < len(c) < 3000  # 1e6 / 400 tiles
    assert np.all(np.diff(c) > 0)


def write_tiles(root: Path, plan: TilePlan, order: list[tuple[int, int]]) -> dict[str, bytes]:
    entries = [write_tile(generate_tile(GRAMMAR, plan, i, j), root, i, j) for i, j in order]
    write_root(root, entries, meta=plan.meta())
    folder = tiles_folder(root)
    files = {p.name: p.read_bytes() for p in sorted(folder.iterdir())}
    files["root"] = root.read_bytes()
    return files


def test_tile_files_byte_identical_in_any_order(tmp_path: Path) -> None:
    plan = TilePlan(24, (24.0, 16.0), 8.0, 11)
    order = list(plan.tiles())
    a = write_tiles(tmp_path / "a" / "f.usdc", plan, order)
    random.Random(5).shuffle(order)
    b = write_tiles(tmp_path / "b" / "f.usdc", plan, order)
    assert len(a) == plan.nx * plan.nz + 1
    assert a == b


def test_root_opens_unloaded_and_loads_one_tile(tmp_path: Path) -> None:
    plan = TilePlan(24, (24.0, 16.0), 8.0, 2)
    root = tmp_path / "forest.usda"
    write_tiles(root, plan, list(plan.tiles()))
    stage = Usd.Stage.Open(str(root), load=Usd.Stage.LoadNone)
    tiles = stage.GetPrimAtPath(TILES).GetAllChildren()
    assert len(tiles) == plan.nx * plan.nz
    assert not stage.GetLoadSet()
    assert all(not p.IsLoaded() and p.HasPayload() for p in tiles)
    assert not stage.GetPrimAtPath(f"{TILES}/T_0_0/Forest")  # nothing of a tile composed
    from pxr import UsdGeom

    for p in tiles:
        lo, hi = UsdGeom.ModelAPI(p).GetExtentsHint()
        assert all(lo[k] <= hi[k] for k in range(3))
    stage.Load(f"{TILES}/T_1_1")
    assert [str(p) for p in stage.GetLoadSet()] == [f"{TILES}/T_1_1"]
    assert stage.GetPrimAtPath(f"{TILES}/T_1_1/Forest/Pieces")
    assert not stage.GetPrimAtPath(f"{TILES}/T_0_0/Forest")
    # the extent hint bounds what the tile holds
    box = (
        UsdGeom.BBoxCache(Usd.TimeCode.Default(), ["default", "render"])
        .ComputeWorldBound(stage.GetPrimAtPath(f"{TILES}/T_1_1"))
        .ComputeAlignedRange()
    )
    lo, hi = UsdGeom.ModelAPI(stage.GetPrimAtPath(f"{TILES}/T_1_1")).GetExtentsHint()
    assert np.allclose(box.GetMin(), lo, atol=1e-4) and np.allclose(box.GetMax(), hi, atol=1e-4)


def test_tile_trees_are_the_plans(tmp_path: Path) -> None:
    plan = TilePlan(30, (20.0, 20.0), 10.0, 4)
    forest = generate_tile(GRAMMAR, plan, 1, 0)
    assert forest is not None
    _, m = plan.tile_trees(1, 0, *SCALE)
    np.testing.assert_array_equal(forest.tree_transforms, m)
    assert forest.options.trees == len(m)


def trees_of(forest: Forest) -> dict[int, dict[str, np.ndarray]]:
    """Each tree's arrays by its id: piece graph (parents relative to the tree), pose, world
    transforms and posed palette."""
    g, pose, palette = forest.graph, forest.pose, forest.palette()
    starts = np.searchsorted(g.tree, np.arange(len(forest.tree_ids) + 1))
    bone_at = np.append(forest.bones.offset, len(forest.bones))
    out = {}
    for t, tree_id in enumerate(forest.tree_ids.tolist()):
        a, b = int(starts[t]), int(starts[t + 1])
        arrays = {f: getattr(g, f)[a:b] for f in g.__dataclass_fields__ if f != "tree"}
        arrays["parent"] = np.where(g.parent[a:b] >= 0, g.parent[a:b] - a, -1)
        arrays |= {f"pose.{f}": getattr(pose, f)[a:b] for f in pose.__dataclass_fields__}
        arrays["model"] = forest.tree_transforms[t]
        arrays["transforms"] = forest.transforms[a:b]
        arrays["palette"] = palette[bone_at[a] : bone_at[b]]
        out[tree_id] = arrays
    return out


@pytest.mark.parametrize(("preset", "placement"), [("almond", "poisson"), ("oak", "grid")])
def test_tiled_forest_equals_untiled_tree_for_tree(preset: str, placement: str) -> None:
    grammar = load_preset(preset)
    trees, area, seed = 23 if preset == "oak" else 40, (30.0, 20.0), 7
    options = ForestOptions(trees=trees, area=area, placement=placement)  # type: ignore[arg-type]
    whole = trees_of(generate_forest(grammar, seed, options))
    plan = TilePlan(trees, area, 10.0, seed)
    tiled: dict[int, dict[str, np.ndarray]] = {}
    for i, j in plan.tiles():
        forest = generate_tile(grammar, plan, i, j, options)
        if forest is not None:
            assert not tiled.keys() & trees_of(forest).keys()  # no tree in two tiles
            tiled |= trees_of(forest)
    assert len(whole) == trees and sorted(tiled) == sorted(whole)  # same placements
    for tree_id, arrays in whole.items():
        assert arrays.keys() == tiled[tree_id].keys()
        for name, a in arrays.items():  # bit for bit: same grammar choices, shape and pose
            np.testing.assert_array_equal(tiled[tree_id][name], a, err_msg=f"{tree_id} {name}")


def test_cli_tile_size(tmp_path: Path) -> None:
    out = tmp_path / "big.usdc"
    res = CliRunner().invoke(
        main,
        [
            "generate",
            "--preset",
            "almond",
            "--trees",
            "30",
            "--area",
            "30",
            "20",
            "--tile-size",
            "10",
            "-o",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "big_tiles").iterdir()) == [
        f"{i}_{j}.usdc" for i in range(3) for j in range(2)
    ]
    stage = Usd.Stage.Open(str(out), load=Usd.Stage.LoadNone)
    assert len(stage.GetPrimAtPath(TILES).GetAllChildren()) == 6
    res = CliRunner().invoke(
        main, ["generate", "--preset", "almond", "--tile-size", "10", "-o", str(tmp_path / "x.glb")]
    )
    assert res.exit_code != 0 and "tile_size" in res.output


def _peak_rss_kb(args: list[str]) -> int:
    """The peak RSS (kB) of ``python -m cli ARGS`` in a process of its own (wait4's rusage:
    this child's alone)."""
    import os
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "cli", *args], stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    assert proc.returncode == 0, args
    return usage.ru_maxrss


def test_tiled_peak_memory_does_not_grow_with_the_tiles(tmp_path: Path) -> None:
    """Six tiles of 30 oaks peak within 10 % of one such tile alone: a tile's memory is given
    back to the next (one allocator arena, the loop holding one tile). Before, the six
    peaked 17 % over the one (2026-11-27; the margin is most of the interpreter's own)."""

    def peak(trees: int, width: int, name: str) -> int:
        out = tmp_path / name / "root.usdc"
        out.parent.mkdir()
        area = ["--area", str(width), "60", "--tile-size", "60"]
        return _peak_rss_kb(["generate", "--preset", "oak", "--trees", str(trees), *area,
                             "-o", str(out), "--quiet"])  # fmt: skip

    one, six = peak(30, 60, "one"), peak(180, 360, "six")
    assert six <= 1.10 * one, (one, six)
