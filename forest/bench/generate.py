"""``forest bench generate``: the vectorised generator against a plain per-piece Python loop
doing the same work (expansion, transforms, posed bones, tiles), and the .usdc write time."""

from __future__ import annotations

import math
import random
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from forest.bark.tiles import class_tables
from forest.geometry import rim
from forest.geometry.pieces import PieceArrays, piece_library, skinning_rest_inverse
from forest.geometry.transforms import axis_angle_matrix
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.grammar import CompiledGrammar, compile_grammar
from forest.growth.presets import load_preset
from forest.growth.scatter import tree_transforms
from forest.growth.skeleton import _piece_tables, _rest_tip_scale
from forest.usd.scene import write_scene
from schemas.tileset import DEFAULT_MANIFEST

Echo = Callable[[str], None]


def baseline_generate(
    cg: CompiledGrammar, pieces: tuple[PieceArrays, ...], n_trees: int, seed: int
) -> int:
    """Grow, assemble, pose and tile piece by piece in Python; returns the piece count."""
    rng = random.Random(seed)
    twists = rim.twists()
    inv_rest = skinning_rest_inverse(pieces)
    tab = _piece_tables(pieces)
    hub_t = tab.hub_t.T
    tip_t = tab.tip_t.T.reshape(len(pieces), -1, 3)
    tip_r = tab.tip_r.T.reshape(len(pieces), -1, 3, 3)
    sigma = _rest_tip_scale(pieces)
    first, count, n_quads = class_tables(pieces, DEFAULT_MANIFEST)
    g = cg.grammar
    trees = tree_transforms(
        n_trees, (20.0, 20.0), g.trunk_radius, g.tree_scale, np.random.default_rng(seed), "grid"
    )
    total = 0
    for t in range(n_trees):
        stack: list[tuple[int, np.ndarray | None, int, int, int]] = [(cg.axiom, None, 0, 0, 0)]
        while stack:
            sym, g_tip, _p_rim, depth, _parent_piece = stack.pop()
            alts = [
                a
                for a in range(len(cg.alt_symbol))
                if cg.alt_symbol[a] == sym and cg.alt_depth[a, 0] <= depth <= cg.alt_depth[a, 1]
            ]
            if not alts:
                continue
            a = rng.choices(alts, weights=[float(cg.alt_weight[i]) for i in alts])[0]
            piece = int(cg.alt_piece[a])
            twist = int(cg.alt_twist[a]) if cg.alt_twist[a] >= 0 else rng.randrange(6)
            root = trees[t] if g_tip is None else g_tip @ twists[twist]
            lo, hi = cg.alt_bend[a]
            bend = axis_angle_matrix(
                [math.cos(rng.random() * 6.28), 0.0, math.sin(rng.random() * 6.28)],
                lo + rng.random() * (hi - lo),
            )
            bend[:3, 3] = hub_t[piece]
            hub = root @ bend
            palette = [root @ inv_rest[piece, 0], hub @ inv_rest[piece, 1]]
            for r in range(pieces[piece].n_leaf_rims):
                lo, hi = cg.alt_spread[a]
                spread = axis_angle_matrix([1.0, 0.0, 0.0], lo + rng.random() * (hi - lo))
                local = np.eye(4)
                local[:3, :3] = spread[:3, :3] @ tip_r[piece, r] * sigma[piece, r]
                local[:3, 3] = tip_t[piece, r]
                tip = hub @ local
                palette.append(tip @ inv_rest[piece, 2 + r])
                succ = int(cg.alt_succ[a, r])
                if succ >= 0 and depth < cg.max_depth:
                    stack.append((succ, tip, r, depth + 1, piece))
            _tiles = [
                int(first[piece, q]) + rng.randrange(int(count[piece, q]))
                for q in range(int(n_quads[piece]))
            ]
            total += 1
    return total


def run_generate_bench(trees: int, preset: str, repeat: int, echo: Echo = print) -> dict:
    grammar = load_preset(preset)
    cg = compile_grammar(grammar)
    pieces = piece_library(1)
    options = ForestOptions(trees=trees, area=(400.0, 400.0), placement="grid")

    def vectorised() -> Forest:
        forest = generate_forest(grammar, 1, options, compiled=cg)
        forest.palette()  # the posed palette: pose is part of the measured work
        return forest

    # the baseline is ~50x slower: it runs on a slice of the forest and both report pieces/s.
    # Runs alternate, so both sides see the same machine; each side keeps its best time.
    base_trees = max(1, min(trees, 200))
    t0 = time.perf_counter()
    forest = vectorised()  # cold: first-touch page faults and lazy imports included
    t_cold = time.perf_counter() - t0
    n_vec = forest.n_instances
    t_vec = t_base = math.inf
    n_base = 0
    for _ in range(repeat):
        del forest  # free the last forest first, as a process making one after another
        t0 = time.perf_counter()
        forest = vectorised()
        t_vec = min(t_vec, time.perf_counter() - t0)
        t0 = time.perf_counter()
        n_base = baseline_generate(cg, pieces, base_trees, 1)
        t_base = min(t_base, time.perf_counter() - t0)
    rate_vec, rate_base = n_vec / t_vec, n_base / t_base
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "forest.usdc"
        t0 = time.perf_counter()
        write_scene(forest, out)
        t_write = time.perf_counter() - t0
        size = out.stat().st_size
    echo(
        f"preset {preset}, {trees} trees, {n_vec} pieces; best of {repeat} alternating runs "
        "after a cold one"
    )
    echo(f"{'':34}{'pieces':>10}{'seconds':>10}{'pieces/s':>14}")
    echo(f"{'vectorised, cold first run':34}{n_vec:>10}{t_cold:>10.3f}{n_vec / t_cold:>14,.0f}")
    echo(f"{'vectorised (per depth level)':34}{n_vec:>10}{t_vec:>10.3f}{rate_vec:>14,.0f}")
    echo(f"{'baseline (per-piece Python loop)':34}{n_base:>10}{t_base:>10.3f}{rate_base:>14,.0f}")
    echo(f"speed-up: {rate_vec / rate_base:.0f}x   (targets: >= 1,000,000 pieces/s, >= 50x)")
    echo(f"write .usdc: {t_write:.2f} s for {trees} trees, {size / 1e6:.0f} MB   (target < 5 s)")
    return {
        "pieces": n_vec,
        "seconds": t_vec,
        "pieces_per_s": rate_vec,
        "cold_seconds": t_cold,
        "baseline_pieces_per_s": rate_base,
        "speedup": rate_vec / rate_base,
        "write_s": t_write,
        "bytes": size,
    }
