"""The forest cost estimate (``forest.cost``) against what generating and writing a forest
measures (peak RSS of a process of its own, the file's bytes): never below, and not so far
above that it refuses what would fit. A writer that grows past its figures fails here."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from forest.cost import forest_cost
from forest.growth.compile import compile_grammar
from forest.growth.presets import load_preset

ROOT = Path(__file__).parents[1]
MEASURE = """
import json, sys
from pathlib import Path
from forest.growth.generate import ForestOptions, generate_forest
from forest.growth.presets import load_preset
preset, trees, frames, segments, fmt, skinned = json.loads(sys.argv[1])
forest = generate_forest(
    load_preset(preset), 1, ForestOptions(trees=trees, frames=frames, segments=segments)
)
out = Path(sys.argv[2])
if fmt == "glb":
    from forest.gltf.document import write_glb
    write_glb(forest, out)
else:
    from forest.usd.scene import write_scene
    write_scene(forest, out, skinned=skinned)
# VmHWM: this process's own peak (ru_maxrss carries the forking parent's peak across exec,
# so a test process grown to 1.8 GB by earlier tests would be measured instead)
hwm = next(line for line in open("/proc/self/status") if line.startswith("VmHWM:"))
rss = int(hwm.split()[1]) * 1024
print(json.dumps({"memory": rss, "scene": out.stat().st_size, "pieces": forest.n_instances}))
"""


@pytest.mark.parametrize(
    ("preset", "trees", "frames", "segments", "fmt", "skinned"),
    [
        ("alternating", 200, 12, 1, "usdc", None),  # posed (over 64 trees)
        ("alternating", 20, 4, 8, "usdc", True),  # skinned, fine pieces
        ("oak", 1, 24, 1, "usdc", None),  # one big skinned tree: the impostor bake's peak
        ("alternating", 20, 4, 1, "glb", None),
    ],
)
def test_estimate_bounds_what_a_forest_costs(
    tmp_path: Path,
    preset: str,
    trees: int,
    frames: int,
    segments: int,
    fmt: str,
    skinned: bool | None,
) -> None:
    args = [preset, trees, frames, segments, fmt, skinned]
    out = subprocess.run(
        [sys.executable, "-c", MEASURE, json.dumps(args), str(tmp_path / f"scene.{fmt}")],
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    measured = json.loads(out.stdout.splitlines()[-1])
    expected = compile_grammar(load_preset(preset)).expected_pieces * trees
    assert expected == pytest.approx(measured["pieces"], rel=0.2)
    cost = forest_cost(expected, trees, frames, segments, fmt, skinned)
    for what, estimate in (("memory", cost.memory_bytes), ("scene", cost.scene_bytes)):
        actual = measured[what]
        assert actual <= estimate <= 4 * actual, (what, actual, estimate)


def test_the_issue_forest_is_over_the_default_caps() -> None:
    """10,000 trees x 44 frames measured 9.5 GB of memory: over a worker's 8 Gi."""
    pieces = compile_grammar(load_preset("alternating")).expected_pieces * 10_000
    cost = forest_cost(pieces, 10_000, 44)
    assert cost.memory_bytes > 6 << 30 and cost.scene_bytes > 2 << 30
