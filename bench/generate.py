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

from bench.floor import page_cache_write_seconds, timed_saves
from bench.rss import peak_bytes, reset_peak
from forest.bark.tiles import class_tables
from forest.geometry import rim
from forest.geometry.pieces import PieceArrays, piece_library, skinning_rest_inverse
from forest.geometry.transforms import axis_angle_matrix, similarity_scale
from forest.growth.compile import compile_grammar
from forest.growth.expand import (
    FINISH_TAPER,
    MAX_FINISH,
    TIP_RADIUS_M,
    crown_shape,
    rim_tables,
)
from forest.growth.generate import Forest, ForestOptions, generate_forest
from forest.growth.grammar import CompiledGrammar
from forest.growth.poser import piece_tables
from forest.growth.presets import load_preset
from forest.growth.scatter import tree_transforms
from forest.usd.figures import scene_figures
from forest.usd.scene import write_scene
from schemas.tileset import DEFAULT_MANIFEST

Echo = Callable[[str], None]


def baseline_generate(
    cg: CompiledGrammar, pieces: tuple[PieceArrays, ...], n_trees: int, seed: int
) -> int:
    """Grow, assemble, pose and tile piece by piece in Python, with the grammar's botanical
    rules (pipe model, taper, crown, twig ends and caps, rolls, branch angles, tropisms from
    each piece's world axis); returns the piece count."""
    rng = random.Random(seed)
    twists = rim.twists()
    inv_rest = skinning_rest_inverse(pieces)
    tab = piece_tables(pieces)
    hub_t = tab.hub_t.T
    tip_t = tab.tip_t.T.reshape(len(pieces), -1, 3)
    tip_r = tab.tip_r.T.reshape(len(pieces), -1, 3, 3)
    rims = rim_tables()
    sigma, rim_y, hub_y, tilt, tilt_az = rims.sigma, rims.rim_y, rims.hub_y, rims.tilt, rims.tilt_az
    first, count, n_quads = class_tables(pieces, DEFAULT_MANIFEST)
    g = cg.grammar
    crown = g.crown
    close = g.close_tips and cg.cap_alt >= 0
    last_finish = cg.max_depth + MAX_FINISH
    trees = tree_transforms(n_trees, (20.0, 20.0), g.trunk_radius, g.tree_scale, seed, "grid")
    total = 0

    def tilt_toward(m: np.ndarray, d: np.ndarray, k: float) -> tuple[float, float]:
        local = m[:3, :3].T @ d
        local /= np.linalg.norm(local)
        return math.atan2(-local[0], local[2]), k * math.acos(max(-1.0, min(1.0, local[1])))

    def add(az0: float, a0: float, az1: float, a1: float) -> tuple[float, float]:
        x = a0 * math.cos(az0) + a1 * math.cos(az1)
        z = a0 * math.sin(az0) + a1 * math.sin(az1)
        return math.atan2(z, x), math.hypot(x, z)

    for t in range(n_trees):
        r0 = float(similarity_scale(trees[t]))
        top_h = rng.uniform(*crown.height) if crown else math.inf
        centre = trees[t][:3, 3]
        # symbol, parent terminal, depth, order, radius (m), height (m), roll, cap
        stack: list[tuple] = [(cg.axiom, None, 0, 0, r0, 0.0, 0.0, False)]
        while stack:
            sym, g_tip, depth, order, scale, h, roll, cap = stack.pop()
            alts = [
                a
                for a in range(len(cg.alt_symbol))
                if cg.alt_symbol[a] == sym
                and cg.alt_depth[a, 0] <= depth <= cg.alt_depth[a, 1]
                and cg.alt_weight[a] > 0
            ]
            if cap or not alts:
                if not close:
                    continue
                a = cg.cap_alt
                # a branch stopped thicker than a twig finishes as tapering straight pieces
                if cg.finish_alt >= 0 and scale > TIP_RADIUS_M and depth <= last_finish:
                    a = cg.finish_alt
            else:
                a = rng.choices(alts, weights=[float(cg.alt_weight[i]) for i in alts])[0]
            piece = int(cg.alt_piece[a])
            twist = int(cg.alt_twist[a]) if cg.alt_twist[a] >= 0 else rng.randrange(6)
            if not math.isnan(cg.alt_roll[a]):
                twist = int((round((roll + cg.alt_roll[a]) / 60) - round(roll / 60)) % 6)
                roll += float(cg.alt_roll[a])
            root = trees[t] if g_tip is None else g_tip @ twists[twist]
            lo, hi = cg.alt_bend[a]
            az, ang = rng.random() * 6.28, lo + rng.random() * (hi - lo)
            gravity, light = cg.alt_tropism[a]
            if gravity:
                d = np.array([0.0, math.copysign(1.0, gravity), 0.0])
                az, ang = add(az, ang, *tilt_toward(root, d, abs(gravity)))
            if light:
                out = root[:3, 3] - centre
                out[1] = 0.0
                out /= max(float(np.linalg.norm(out)), 1e-12)
                out[1] = 1.0
                az, ang = add(az, ang, *tilt_toward(root, out / np.linalg.norm(out), light))
            bend = axis_angle_matrix([math.cos(az), 0.0, math.sin(az)], ang)
            bend[:3, 3] = hub_t[piece]
            hub = root @ bend
            palette = [root @ inv_rest[piece, 0], hub @ inv_rest[piece, 1]]
            n_rims = pieces[piece].n_leaf_rims
            w = [rng.uniform(*cg.alt_radius[a, r]) for r in range(n_rims)]
            lengths = [rng.uniform(*cg.alt_length[a, r]) for r in range(n_rims)]
            taper = rng.uniform(*cg.alt_taper[a])
            kids = []
            for r in range(n_rims):
                c_h = h + (hub_y[piece] if r else rim_y[piece, r]) * scale
                bare = False
                if crown and order == 0 and r:
                    rel = c_h / top_h
                    bare = rel < crown.base
                    w[r] *= 0.15 if bare else float(crown_shape(crown.shape, np.array(rel)))
                kids.append((c_h, bare))
            if cg.pipe_exponent:
                norm = sum(x**cg.pipe_exponent for x in w) ** (1 / cg.pipe_exponent)
                s = [taper * x / norm for x in w]
            else:
                s = [taper * sigma[piece, r] * w[r] for r in range(n_rims)]
            if a == cg.finish_alt:
                s = [max(TIP_RADIUS_M / scale, FINISH_TAPER)]
            for r in range(n_rims):
                c_h, bare = kids[r]
                lo, hi = cg.alt_spread[a]
                s_az, s_ang = rng.random() * 6.28, lo + rng.random() * (hi - lo)
                if not math.isnan(cg.alt_branch_angle[a, 0]) and tilt[piece, r] > 1e-3:
                    want = rng.uniform(*cg.alt_branch_angle[a])
                    s_az, s_ang = add(s_az, s_ang, tilt_az[piece, r], want - tilt[piece, r])
                spread = axis_angle_matrix([math.cos(s_az), 0.0, math.sin(s_az)], s_ang)
                local = np.eye(4)
                local[:3, :3] = spread[:3, :3] @ tip_r[piece, r] * s[r]
                local[:3, 3] = tip_t[piece, r] * lengths[r]
                tip = hub @ local
                palette.append(tip @ inv_rest[piece, 2 + r])
                succ = int(cg.alt_succ[a, r])
                c_scale, c_order = scale * s[r], order + (r > 0)
                ends = (
                    succ < 0
                    or depth >= cg.max_depth
                    or bare
                    or (g.twig_radius is not None and c_scale < g.twig_radius)
                    or (c_order == 0 and c_h >= top_h)
                )
                if not ends or close:
                    c_roll = roll if r == 0 else 0.0
                    stack.append((succ, tip, depth + 1, c_order, c_scale, c_h, c_roll, ends))
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
    per_tree = max(cg.expected_pieces, 1.0)
    base_trees = max(1, min(trees, int(12_400 / per_tree)))  # about 12k pieces
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
        # the write's own peak: the high-water mark restarts at the present RSS (the
        # forest's arrays), apart from the generation runs above
        reset = reset_peak()
        rss_before = peak_bytes()
        with timed_saves() as saves:
            t0 = time.perf_counter()
            write_scene(forest, out, skinned=False)  # the instanced writer, whatever --trees
            t_write = time.perf_counter() - t0
        peak = peak_bytes()  # the forest in memory and its write (after a reset: this alone)
        size = out.stat().st_size
        t_floor = page_cache_write_seconds(Path(tmp), size)  # same bytes, same folder
        # one tree as an artist gets it (the default form of a one-tree .usdc), measured
        # from the written file alone: what a tree weighs, beside the forest's bytes a tree
        tree_path = Path(tmp) / "tree.usdc"
        write_scene(generate_forest(grammar, 1, ForestOptions(trees=1, area=(1.0, 1.0))), tree_path)
        tree = scene_figures(tree_path).trees[0]
        tree_bytes = tree_path.stat().st_size
    t_save = sum(saves)
    t_author = t_write - t_save
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
    echo(
        f"  of which Save {t_save:.2f} s (the rest: posing, fitting, authoring); page-cache "
        f"floor for the same bytes {t_floor:.3f} s: write {t_write / t_floor:.1f}x, "
        f"Save {t_save / t_floor:.1f}x the floor   (target: write <= 2x)"
    )
    echo(
        f"  author (everything but Save: anchors, fits, extents, conversions, authoring) "
        f"{t_author:.2f} s = {t_author / t_save:.2f}x Save   (target <= 1x)"
    )
    echo(
        f"  peak RSS during the write {peak / 1e9:.2f} GB (the forest's arrays included; "
        f"{rss_before / 1e9:.2f} GB before it)"
        if reset
        else f"  peak RSS of the process {peak / 1e9:.2f} GB (no per-step reset here)"
    )
    echo(
        f"one tree (seed 1, default .usdc): {tree.triangles:,} triangles "
        f"({tree.bark_triangles:,} bark, {tree.leaf_triangles:,} leaves), {tree.cards:,} leaf "
        f"cards, {tree_bytes / 1e6:.2f} MB; the forest's instanced .usdc: "
        f"{size / trees / 1e3:.1f} kB a tree"
    )
    return {
        "tree_triangles": tree.triangles,
        "tree_bark_triangles": tree.bark_triangles,
        "tree_leaf_triangles": tree.leaf_triangles,
        "tree_bytes": tree_bytes,
        "forest_bytes_per_tree": size / trees,
        "pieces": n_vec,
        "seconds": t_vec,
        "pieces_per_s": rate_vec,
        "cold_seconds": t_cold,
        "baseline_pieces_per_s": rate_base,
        "speedup": rate_vec / rate_base,
        "write_s": t_write,
        "save_s": t_save,
        "floor_s": t_floor,
        "write_over_floor": t_write / t_floor,
        "author_s": t_author,
        "author_over_save": t_author / t_save,
        "write_peak_rss_bytes": peak,
        "bytes": size,
    }
