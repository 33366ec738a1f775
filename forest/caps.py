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
up to 1.02 and 1.43. A .glb's vertices are those of its profile (:func:`glb_vertices`): the
game profile's levels wrote 0.86-0.89 of the estimate over every preset (2026-11-27, 2
trees each). A forest the estimate lets through is counted again once grown
(:func:`forest.growth.generate.generate_forest`, :func:`forest.gltf.document.check_size`).

A mixed stand's layers (:mod:`forest.stand`) are estimated at their trees' sizes
(:func:`layer_estimates`: one tree grown at each of 8 quantiles of the layer's size
distribution) and all checked before the first layer grows (:func:`check_layers`); mixed-
broadleaf, 20 trees, 2026-11-27: each layer's grown bones 0.80-0.96 of the estimate, the
stand's baked vertices 0.87 (as mature trees: 0.16 for its young oaks, 0.66 for the stand)."""

from __future__ import annotations

from collections.abc import Sequence
from statistics import NormalDist
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from forest.errors import LimitError
from forest.geometry.pieces import piece_library
from forest.growth.foliage import cloud_models
from forest.growth.grammar import CompiledGrammar
from forest.lod.targets import BARK_SHARE, GAME_LOD0, TARGETS
from forest.settings import ForestSettings

if TYPE_CHECKING:  # a forest of one species never loads the recipe schemas (start-up)
    from schemas.recipe import Recipe, SizeDistribution

# trees grown per layer to estimate a mixed stand's layer, one at each of this many quantiles
# of its size distribution: a few hundredths of a second for an oak
LAYER_SAMPLE_TREES = 8
# vertices per .glb (bark and leaves, as glb_vertices estimates them): 100 game oaks (about
# 21 M written, a 525 MB file, 1.7 GB peak while written; 2026-11-27) or 43 film ones
# (about 100 bytes of peak memory and 35 of file a vertex)
MAX_VERTICES = 25_000_000
# welded game bark on its repeating picture: glTF vertices per bark quad (an oak's LOD0:
# 1.33, docs/gltf.md); the film profile's atlas needs 4, one per quad corner
GAME_BARK_PER_QUAD = 1.34
# a game level keeps its bark and leaves in about, not exactly, their shares of the triangles
# (an oak's LOD0 kept 68 % leaves for a 63 % share): the estimate's margin
GAME_MARGIN = 1.1
IMPOSTOR_VERTICES = 8  # LOD3: the crossed card pair


def glb_vertices(
    bark_quads: float,
    leaf_vertices: float,
    leaf_triangles: float,
    profile: str = "game",
    lod0_triangles: int | None = None,
) -> float:
    """One tree's vertices in a .glb of ``profile`` from its full tree's bark quads and leaf
    cards. film: every bark quad corner its own vertex, and the cards'. game: LOD0 (the full
    tree scaled to its budget, bark welded, :data:`GAME_BARK_PER_QUAD`), the lower levels'
    leaf cards (their bark is LOD0's vertices, indexed again) and the impostor, times
    :data:`GAME_MARGIN`; an oak's 579 k film vertices are about 210 k."""
    if profile == "film":
        return 4.0 * bark_quads + leaf_vertices
    full = 2.0 * bark_quads + leaf_triangles
    if full <= 0:
        return 0.0
    lod0 = GAME_LOD0.budget if lod0_triangles is None else lod0_triangles
    keep = min(1.0, lod0 / full)
    n = keep * (GAME_BARK_PER_QUAD * bark_quads + leaf_vertices)
    per_triangle = leaf_vertices / leaf_triangles if leaf_triangles else 0.0
    for target in TARGETS[1:]:  # of the full tree's triangles, as forest.lod.levels
        n += (1.0 - BARK_SHARE) * target.triangles(int(full)) * per_triangle
    return GAME_MARGIN * n + IMPOSTOR_VERTICES


def _per_tree(cg: CompiledGrammar, per_kind: NDArray[np.float64]) -> float:
    """``per_kind`` (a value per piece kind) summed over a tree's expected pieces; a grammar
    built without the kinds (by hand) counts every piece as the heaviest kind."""
    if not len(cg.expected_kinds):
        return cg.expected_pieces * float(per_kind.max())
    return float(cg.expected_kinds @ per_kind)


def expected_bones(cg: CompiledGrammar) -> float:
    """Expected bones per tree: each piece kind's joints."""
    return _per_tree(cg, np.array([p.n_joints for p in piece_library()], np.float64))


def expected_vertices(
    cg: CompiledGrammar,
    segments: int = 1,
    profile: str = "film",
    lod0_triangles: int | None = None,
) -> float:
    """Expected vertices per tree of a .glb of ``profile`` (:func:`glb_vertices`, as
    :func:`forest.gltf.document.baked_vertices` counts them from a grown forest): the bark
    quads, and the leaf sprays' (each bearer's mean sprays of the mean model, no more than
    ``leaves.max_triangles`` allows a tree)."""
    quads = _per_tree(cg, np.array([len(p.quads) for p in piece_library(segments)], float))
    leaves = cg.grammar.leaves
    models = cloud_models(leaves.family, leaves.length, leaves.phyllotaxis)
    sprays = cg.expected_bearers * sum(leaves.sprays) / 2
    leaf = sprays * float(np.mean([len(c.positions) for c in models]))
    triangles = sprays * float(np.mean([2 * c.n_cards for c in models]))
    if leaves.max_triangles is not None:
        # the most vertices a triangle of any model brings: the sprays a tree keeps stop there
        per_tri = max(len(c.positions) / (2 * c.n_cards) for c in models)
        if leaf > leaves.max_triangles * per_tri:
            triangles *= leaves.max_triangles * per_tri / leaf
            leaf = leaves.max_triangles * per_tri
    return glb_vertices(quads, leaf, triangles, profile, lod0_triangles)


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


def check_glb_vertices(
    cg: CompiledGrammar,
    trees: int,
    segments: int = 1,
    profile: str = "game",
    lod0_triangles: int | None = None,
) -> None:
    """``trees`` trees' expected .glb vertices (``profile``, the writer's default game)
    within the glTF writer's cap."""
    n = expected_vertices(cg, segments, profile, lod0_triangles) * trees
    if n > MAX_VERTICES:
        raise LimitError(
            f"{trees} trees bake to about {n:.0f} vertices in a {profile} .glb, over the glTF "
            f"cap of {MAX_VERTICES}; use fewer trees (or USD, which instances the pieces)",
            path="trees",
            limit=MAX_VERTICES,
        )


def check_forest_pieces(cg: CompiledGrammar, trees: int, settings: ForestSettings) -> None:
    """``trees`` trees' expected pieces within ``max_pieces_per_forest``."""
    expected = cg.expected_pieces * trees
    if expected > settings.max_pieces_per_forest:
        raise LimitError(
            f"{trees} trees of about {cg.expected_pieces:.0f} pieces each "
            f"exceed the cap of {settings.max_pieces_per_forest} pieces per forest",
            path="max_pieces_per_forest",
            limit=settings.max_pieces_per_forest,
        )


def size_quantiles(size: SizeDistribution, k: int = LAYER_SAMPLE_TREES) -> NDArray[np.float64]:
    """``k`` sizes at the mid-quantiles of a recipe layer's size distribution (clipped as
    :func:`forest.stand.place` clips the drawn sizes): the trees the layer's estimate grows."""
    from schemas.recipe import SIZE_MAX, SIZE_MIN

    q = (np.arange(k) + 0.5) / k
    if size.range is not None:
        lo, hi = size.range
        s = lo + q * (hi - lo)
    else:
        mean, sd = size.normal or (1.0, 0.0)
        s = np.array([NormalDist(mean, sd).inv_cdf(x) if sd > 0 else mean for x in q])
    return np.clip(s, SIZE_MIN, SIZE_MAX)


def layer_estimates(
    recipe: Recipe, compiled: Sequence[CompiledGrammar], settings: ForestSettings
) -> list[CompiledGrammar]:
    """Each layer's grammar with its expected counts at the layer's sizes
    (:func:`forest.growth.compile.at_sizes`): a mature tree's would count a recipe's young
    oaks 10-15 times over."""
    from forest.growth.compile import at_sizes

    return [
        at_sizes(cg, size_quantiles(layer.size), settings)
        for cg, layer in zip(compiled, recipe.layers, strict=True)
    ]


def check_layers(
    compiled: Sequence[CompiledGrammar],
    counts: Sequence[int],
    names: Sequence[str],
    frames: int,
    settings: ForestSettings,
    *,
    glb: bool = False,
    segments: int = 1,
    profile: str = "game",
    lod0_triangles: int | None = None,
) -> None:
    """A mixed stand's caps before its first layer grows: each layer is a forest of its own
    (its pieces and its palette within the per-forest caps), and a .glb holds every layer's
    baked vertices. Layers grow one at a time, so without this a later layer over a cap was
    refused only after the earlier ones were grown and written (and a .glb's vertices only
    layer by layer, once grown). ``compiled``: each layer's estimate at its sizes
    (:func:`layer_estimates`); ``profile``, ``lod0_triangles``: the .glb's, as it is written
    (the stand writer's default is the game profile)."""
    for cg, n, name in zip(compiled, counts, names, strict=True):
        if n < 1:
            continue
        try:
            check_forest_pieces(cg, n, settings)
            check_palette(cg, n, frames, settings)
        except LimitError as exc:
            raise LimitError(
                f"layer {name!r}: {exc.message}", path=exc.path, limit=exc.limit
            ) from None
    if glb:
        total = sum(
            expected_vertices(cg, segments, profile, lod0_triangles) * n
            for cg, n in zip(compiled, counts, strict=True)
        )
        if total > MAX_VERTICES:
            raise LimitError(
                f"the stand's {sum(counts)} trees bake to about {total:.0f} vertices, over the "
                f"glTF cap of {MAX_VERTICES}; use fewer trees (or USD, which instances the "
                "pieces)",
                path="trees",
                limit=MAX_VERTICES,
            )
