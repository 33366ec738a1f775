"""Shared by the glTF tests: a small animated forest, the library's own skinning of its baked
bark meshes (one vertex per quad corner, as forest.gltf writes them), and the Node tools."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
from helpers_skin import cut_palette, skin_forest

from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.joint_budget import GAME_JOINTS
from forest.growth.presets import load_preset
from forest.usd.skinned import tree_slices

ROOT = Path(__file__).resolve().parents[1]
NODE_DIR = ROOT / "tests" / "node"
TREES, FRAMES, FPS = 2, 6, 24.0
CHECK_FRAMES = (0, 3)  # the two frames whose skinned vertices the consumers must reproduce


def small_forest(frames: int = FRAMES) -> Forest:
    return generate_forest(
        load_preset("almond"), 3, ForestOptions(trees=TREES, frames=frames, fps=FPS)
    )


def expected_bark(forest: Forest, time: float | None) -> list[np.ndarray]:
    """Per tree ``(4 q, 3)``: every quad corner of the tree's pieces skinned with the forest's
    palette at ``time`` as the skins' joints (GAME_JOINTS per tree) carry it (world space,
    y up), in the order the GLB's bark mesh holds them."""
    pos, _ = skin_forest(forest, cut_palette(forest, forest.palette(time), GAME_JOINTS))
    out = []
    for inst, _bones in tree_slices(forest):
        points, quads, base = [], [], 0
        for i in range(inst.start, inst.stop):
            piece = forest.pieces[forest.graph.piece[i]]
            points.append(pos[i])
            quads.append(piece.quads + base)
            base += len(piece.positions)
        out.append(np.concatenate(points)[np.concatenate(quads).ravel()])
    return out


def tree_heights(expected: list[np.ndarray]) -> list[float]:
    return [float(p[:, 1].max() - p[:, 1].min()) for p in expected]


def node_tools() -> str | None:
    """Why the Node tools cannot run, or None when they can."""
    if shutil.which("node") is None:
        return "node is not installed (the CI script installs nodejs and npm)"
    if not (NODE_DIR / "node_modules" / "gltf-validator").is_dir():
        return "tests/node/node_modules is missing: run `npm ci` in tests/node (.ci/run does)"
    return None


def run_node(script: str, *args: str) -> dict[str, Any]:
    proc = subprocess.run(
        ["node", str(NODE_DIR / script), *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=NODE_DIR,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    result: dict[str, Any] = json.loads(proc.stdout)
    return result
