"""The caps that follow from a grown forest's size, checked before it is grown: palette
matrices (bones x frames) and a .glb's baked vertices, estimated from the compiled grammar's
expected pieces of each kind (:attr:`forest.growth.grammar.CompiledGrammar.expected_kinds`).

The estimates carry the expected pieces' margin: grammars that end by thickness or height,
and those that close their tips (caps and finishing chains follow the radii there), are
sampled and scaled by 1.15 (:data:`forest.growth.compile.SAMPLE_MARGIN`); the rest are counted
level by level, at the exact mean. Measured on 2026-11-27 over every shipped preset (seeds
1-3; 1, 10 and 40 trees; segments 1 and 8 for oak and willow): the sampled presets' grown
bones came to 0.72-0.99 of the estimate (0.87-0.93 from 10 trees on), their baked vertices to
0.74-0.997; the level-counted ones' bones to 1.00 (alternating) and, by the spread of single
trees, up to 1.39 (uniform, 1 tree), 1.14 (10 trees), 0.87-0.98 (100 trees), their vertices
up to 1.02 and 1.43. A forest the estimate lets through is counted again once grown
(:func:`forest.growth.generate.generate_forest`, :func:`forest.gltf.document.check_size`)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from forest.errors import LimitError
from forest.geometry.pieces import piece_library
from forest.growth.foliage import cloud_models
from forest.growth.grammar import CompiledGrammar
from forest.settings import ForestSettings

MAX_VERTICES = 8_000_000  # baked vertices per .glb (bark and leaves): about 450 MB of GLB


def _per_tree(cg: CompiledGrammar, per_kind: NDArray[np.float64]) -> float:
    """``per_kind`` (a value per piece kind) summed over a tree's expected pieces; a grammar
    built without the kinds (by hand) counts every piece as the heaviest kind."""
    if not len(cg.expected_kinds):
        return cg.expected_pieces * float(per_kind.max())
    return float(cg.expected_kinds @ per_kind)


def expected_bones(cg: CompiledGrammar) -> float:
    """Expected bones per tree: each piece kind's joints."""
    return _per_tree(cg, np.array([p.n_joints for p in piece_library()], np.float64))


def expected_vertices(cg: CompiledGrammar, segments: int = 1) -> float:
    """Expected baked vertices per tree of a .glb (as :func:`forest.gltf.document.
    baked_vertices` counts them): 4 per bark quad, and the leaf sprays' (each bearer's mean
    sprays of the mean model, no more than ``leaves.max_triangles`` allows a tree)."""
    bark = 4.0 * _per_tree(cg, np.array([len(p.quads) for p in piece_library(segments)], float))
    leaves = cg.grammar.leaves
    models = cloud_models(leaves.family, leaves.length, leaves.phyllotaxis)
    per_spray = float(np.mean([len(c.positions) for c in models]))
    leaf = cg.expected_bearers * sum(leaves.sprays) / 2 * per_spray
    if leaves.max_triangles is not None:
        # the most vertices a triangle of any model brings: the sprays a tree keeps stop there
        per_tri = max(len(c.positions) / (2 * c.n_cards) for c in models)
        leaf = min(leaf, leaves.max_triangles * per_tri)
    return bark + leaf


def check_palette(cg: CompiledGrammar, trees: int, frames: int, settings: ForestSettings) -> None:
    """``trees`` trees' expected bones x ``frames`` within ``max_palette_matrices``."""
    bones = expected_bones(cg) * trees
    matrices = bones * max(frames, 1)
    if matrices > settings.max_palette_matrices:
        raise LimitError(
            f"about {bones:.0f} bones x {max(frames, 1)} frame(s) = {matrices:.0f} palette "
            f"matrices expected, over the cap of {settings.max_palette_matrices}; use fewer "
            "frames or trees",
            path="max_palette_matrices",
            limit=settings.max_palette_matrices,
        )


def check_glb_vertices(cg: CompiledGrammar, trees: int, segments: int = 1) -> None:
    """``trees`` trees' expected baked vertices within the glTF writer's cap."""
    n = expected_vertices(cg, segments) * trees
    if n > MAX_VERTICES:
        raise LimitError(
            f"{trees} trees bake to about {n:.0f} vertices, over the glTF cap of "
            f"{MAX_VERTICES}; use fewer trees (or USD, which instances the pieces)",
            path="trees",
            limit=MAX_VERTICES,
        )
